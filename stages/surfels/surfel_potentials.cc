// Potentials of the oriented particle system and their exact gradients (see surfel_potentials.h;
// seed 000 section 5, lines 4454-4586).
#include "stages/surfels/surfel_potentials.h"

#include <cmath>

namespace ibmr {

double PairEnergy(const Eigen::Vector3d& p_i, const Eigen::Vector3d& n_i, const Eigen::Vector3d& p_j,
                  const Eigen::Vector3d& n_j, double spacing, const ParticleWeights& w, PairGradient* gradient,
                  Curvature* curvature) {
  const Eigen::Vector3d u = (p_j - p_i) / spacing;
  const double d2 = u.squaredNorm();
  const double d = std::sqrt(d2);
  const double inv_sigma2 = 1.0 / (w.sigma * w.sigma);
  const double psi = std::exp(-0.5 * d2 * inv_sigma2);
  const double a_i = n_i.dot(u), a_j = n_j.dot(u);
  const Eigen::Vector3d sum = n_i + n_j, difference = n_i - n_j;
  const double b = sum.dot(u);
  const double shape = w.coplanarity * (a_i * a_i + a_j * a_j) + w.conormality * difference.squaredNorm() +
                       w.cocircularity * b * b;
  const double h = w.repulsion_radius;
  const double gap = d < h ? 1.0 - d / h : 0.0;
  const double energy = psi * shape + w.repulsion * gap * gap;
  if (gradient) {
    Eigen::Vector3d d_u = psi * (2 * w.coplanarity * (a_i * n_i + a_j * n_j) + 2 * w.cocircularity * b * sum) -
                          shape * psi * inv_sigma2 * u;
    if (gap > 0 && d > 0) d_u += w.repulsion * 2 * gap * (-1.0 / h) * (u / d);
    gradient->p_j += d_u / spacing;
    gradient->p_i -= d_u / spacing;
    gradient->n_i += psi * (2 * w.coplanarity * a_i * u + 2 * w.conormality * difference + 2 * w.cocircularity * b * u);
    gradient->n_j += psi * (2 * w.coplanarity * a_j * u - 2 * w.conormality * difference + 2 * w.cocircularity * b * u);
  }
  if (curvature) {
    const double r2 = d2 * inv_sigma2;
    curvature->position += psi * (4 * w.coplanarity + 8 * w.cocircularity) * (1 + r2) + (gap > 0 ? 2 * w.repulsion / (h * h) : 0.0);
    curvature->normal += psi * (2 * w.conormality + 2 * (w.coplanarity + w.cocircularity) * d2);
  }
  return energy;
}

double DataEnergy(const Eigen::Vector3d& p, const Eigen::Vector3d& n, const Eigen::Vector3d& q, double confidence,
                  double spacing, const ParticleWeights& w, Eigen::Vector3d* grad_p, Eigen::Vector3d* grad_n,
                  Curvature* curvature) {
  const Eigen::Vector3d v = (q - p) / spacing;
  const double inv_sigma2 = 1.0 / (w.data_sigma * w.data_sigma);
  const double psi = std::exp(-0.5 * v.squaredNorm() * inv_sigma2);
  const double a = n.dot(v);
  const double t = w.tangential;
  const double body = (1 - t) * a * a + t * v.squaredNorm();
  const double scale = w.data * confidence;
  if (grad_p) {
    const Eigen::Vector3d d_v = scale * psi * (2 * (1 - t) * a * n + 2 * t * v - body * inv_sigma2 * v);
    *grad_p -= d_v / spacing;
  }
  if (grad_n) *grad_n += scale * psi * 2 * (1 - t) * a * v;
  if (curvature) {
    const double r2 = v.squaredNorm() * inv_sigma2;
    curvature->position += scale * psi * 2 * (1 + r2);
    curvature->normal += scale * psi * 2 * (1 + r2) * v.squaredNorm();
  }
  return scale * psi * body;
}

}  // namespace ibmr
