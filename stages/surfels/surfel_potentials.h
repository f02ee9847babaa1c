// The energy of an oriented particle system (seed 000 section 5, lines 4454-4586, after Szeliski &
// Tonnesen, "Surface modeling with oriented particle systems", SIGGRAPH 1992): particles with a
// position p and a unit normal n interact through potentials that favour locally planar or locally
// spherical arrangements, plus a short-range repulsion that evens their spacing; a data term ties
// each particle to the fused points around it (seed 000 section 4's uncertainty: the points'
// confidence weights them).
//
// Every length is measured in units of the particle spacing s, so the weights are unitless. For a
// pair (i, j) with u = (p_j - p_i) / s and psi(u) = exp(-|u|^2 / (2 sigma^2)):
//   co-planarity   phi_P = psi * ((n_i . u)^2 + (n_j . u)^2)   neighbour on my tangent plane
//   co-normality   phi_N = psi * |n_i - n_j|^2                  neighbours' normals agree
//   co-circularity phi_C = psi * ((n_i + n_j) . u)^2            both on one sphere (zero for any sphere
//                                                               or plane, so it smooths without shrinking)
//   repulsion      phi_R = (1 - |u| / h)^2 for |u| < h, else 0  pushes closer pairs apart to spacing h
// E_pair = w_P phi_P + w_N phi_N + w_C phi_C + w_R phi_R.
// Data term of a particle with data points q_k of confidence c_k, v_k = (q_k - p) / s:
//   E_data = w_D * sum_k c_k psi_D(v_k) ((1 - t) (n . v_k)^2 + t |v_k|^2)
// (psi_D with its own sigma): point-to-plane distances pull the particle onto the data along its
// normal and turn the normal to the data's plane; the small tangential share t keeps particles from
// sliding off the data's edge while the repulsion evens them along the surface.
// The gradients are exact (tested against finite differences); normals are free vectors here, the
// solver keeps them unit.
#pragma once

#include <Eigen/Core>

namespace ibmr {

struct ParticleWeights {
  double coplanarity = 0.2;     // w_P
  double conormality = 1.0;     // w_N
  double cocircularity = 1.0;   // w_C
  double repulsion = 16.0;      // w_R
  double data = 2.0;            // w_D
  double sigma = 1.0;           // interaction radius of psi, in spacings
  double repulsion_radius = 1.2;  // h, in spacings
  double data_sigma = 1.0;      // radius of psi_D, in spacings
  double tangential = 0.05;     // t, share of the tangential data pull, in [0, 1]
};

struct PairGradient {
  Eigen::Vector3d p_i = Eigen::Vector3d::Zero(), n_i = Eigen::Vector3d::Zero();
  Eigen::Vector3d p_j = Eigen::Vector3d::Zero(), n_j = Eigen::Vector3d::Zero();
};

// Upper estimates of the energy's curvature in a particle's position (per spacing^-2) and in its
// normal, summed over its terms: the solver divides the gradient by them (a Jacobi
// preconditioner), so steps stay stable however many neighbours a particle has.
struct Curvature {
  double position = 0;
  double normal = 0;
};

// E_pair of particles i and j (spacing s > 0); adds its gradient to `gradient` and particle i's
// curvature to `curvature` when they are not null.
double PairEnergy(const Eigen::Vector3d& p_i, const Eigen::Vector3d& n_i, const Eigen::Vector3d& p_j,
                  const Eigen::Vector3d& n_j, double spacing, const ParticleWeights& weights,
                  PairGradient* gradient = nullptr, Curvature* curvature = nullptr);

// The data term of one particle and one data point q of confidence c; adds d/dp, d/dn and the
// particle's curvature.
double DataEnergy(const Eigen::Vector3d& p, const Eigen::Vector3d& n, const Eigen::Vector3d& q, double confidence,
                  double spacing, const ParticleWeights& weights, Eigen::Vector3d* grad_p = nullptr,
                  Eigen::Vector3d* grad_n = nullptr, Curvature* curvature = nullptr);

}  // namespace ibmr
