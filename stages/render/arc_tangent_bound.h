// A polynomial arctangent with a known error bound, for ULR's pruned blend search
// (UlrRenderer::Blend): it ranks sources by a lower bound of their penalty, so the angle term needs
// an approximation never off by more than kAngleBound; penalties themselves use std::atan2.
//
// atan2(y, x) for y >= 0 (an angle in [0, pi]): atan(a) for a = min/max of |x|, y in [0, 1] by the
// degree-9 odd polynomial of Abramowitz & Stegun 4.4.49's form, reflected to the octant. Its
// largest error, found by dense sampling (arc_tangent_bound_test.cc), is 1.15e-5 rad; kAngleBound
// allows 8.7 times that. NaN in, NaN or a finite value out: callers test their inputs.
#pragma once

#include <algorithm>
#include <cmath>

namespace ibmr {

constexpr double kAngleBound = 1e-4;

inline double ArcTangentBelowPi(double y, double x) {
  const double ax = std::abs(x);
  const double high = std::max(ax, y), low = std::min(ax, y);
  if (!(high > 0)) return 0.0;
  const double a = low / high, s = a * a;
  double r = ((((0.0208351 * s - 0.0851330) * s + 0.1801410) * s - 0.3302995) * s + 0.9998660) * a;
  if (y > ax) r = 1.5707963267948966 - r;
  if (x < 0) r = 3.141592653589793 - r;
  return r;
}

}  // namespace ibmr
