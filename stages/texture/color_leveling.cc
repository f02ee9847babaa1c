// Exposure gains and global seam leveling (see color_leveling.h).
#include "stages/texture/color_leveling.h"

#include <Eigen/Dense>
#include <Eigen/Sparse>
#include <Eigen/SparseCholesky>
#include <unordered_map>

namespace ibmr {

namespace {

double Luminance(const Eigen::Vector3f& bgr) { return 0.114 * bgr[0] + 0.587 * bgr[1] + 0.299 * bgr[2]; }

}  // namespace

std::vector<double> SolveGains(const FaceObservations& observations, int views, double gain_sigma, double noise_sigma) {
  Eigen::MatrixXd a = Eigen::MatrixXd::Zero(views, views);
  Eigen::VectorXd b = Eigen::VectorXd::Zero(views);
  Eigen::VectorXd pairs = Eigen::VectorXd::Zero(views);
  const double wn = 1.0 / (noise_sigma * noise_sigma);
  for (const auto& list : observations) {
    for (size_t i = 0; i < list.size(); ++i) {
      for (size_t j = i + 1; j < list.size(); ++j) {
        const int v = list[i].view, w = list[j].view;
        const double iv = Luminance(list[i].mean_color), iw = Luminance(list[j].mean_color);
        a(v, v) += wn * iv * iv;
        a(w, w) += wn * iw * iw;
        a(v, w) -= wn * iv * iw;
        a(w, v) -= wn * iv * iw;
        pairs[v] += 1;
        pairs[w] += 1;
      }
    }
  }
  const double wg = 1.0 / (gain_sigma * gain_sigma);
  for (int v = 0; v < views; ++v) {
    const double weight = wg * std::max(1.0, pairs[v]);
    a(v, v) += weight;
    b[v] += weight;
  }
  const Eigen::VectorXd g = a.ldlt().solve(b);
  // The prior also pulls every gain toward 0 with the data term (all-dark photos agree best);
  // dividing by the mean keeps the atlas as bright as the photos on average.
  std::vector<double> gains(views, 1.0);
  double sum = 0;
  for (int v = 0; v < views; ++v) {
    if (std::isfinite(g[v]) && g[v] > 0.05) gains[v] = g[v];
    sum += gains[v];
  }
  for (double& gain : gains) gain *= views / sum;
  return gains;
}

SeamLeveling::SeamLeveling(const TriangleMesh& mesh, const std::vector<int>& labels) : mesh_(mesh), labels_(labels) {
  face_variables_.assign(mesh.faces.size() * 3, -1);
  variables_of_vertex_.resize(mesh.vertices.size());
  faces_of_vertex_.resize(mesh.vertices.size());
  std::unordered_map<uint64_t, int> index;
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    if (labels[f] < 0) continue;
    for (int k = 0; k < 3; ++k) {
      const int vertex = mesh.faces[f][k];
      const uint64_t key = (static_cast<uint64_t>(vertex) << 20) ^ static_cast<uint64_t>(labels[f]);
      auto [it, inserted] = index.emplace(key, static_cast<int>(vertex_of_.size()));
      if (inserted) {
        vertex_of_.push_back(vertex);
        label_of_.push_back(labels[f]);
        variables_of_vertex_[vertex].push_back(it->second);
      }
      face_variables_[f * 3 + k] = it->second;
      faces_of_vertex_[vertex].push_back(static_cast<int>(f));
    }
  }
  for (const std::vector<int>& variables : variables_of_vertex_) {
    if (variables.size() < 2) continue;
    ++seam_vertices_;
    seam_variables_.insert(seam_variables_.end(), variables.begin(), variables.end());
  }
  offsets_.assign(vertex_of_.size(), Eigen::Vector3f::Zero());
}

void SeamLeveling::SetColorsFromFaces(const FaceObservations& observations, const std::vector<double>& gains) {
  terms_.clear();
  const auto color_in = [&](int f, int view, Eigen::Vector3f* color) {
    for (const FaceObservation& o : observations[f]) {
      if (o.view == view) {
        *color = o.mean_color * static_cast<float>(gains[view]);
        return true;
      }
    }
    return false;
  };
  for (size_t v = 0; v < variables_of_vertex_.size(); ++v) {
    const std::vector<int>& variables = variables_of_vertex_[v];
    for (size_t a = 0; a < variables.size(); ++a) {
      for (size_t b = a + 1; b < variables.size(); ++b) {
        const int la = label_of_[variables[a]], lb = label_of_[variables[b]];
        Eigen::Vector3f sum = Eigen::Vector3f::Zero(), ca, cb;
        int count = 0;
        for (int f : faces_of_vertex_[v]) {
          if (color_in(f, la, &ca) && color_in(f, lb, &cb)) sum += cb - ca, ++count;
        }
        if (count > 0) terms_.push_back({variables[a], variables[b], sum / static_cast<float>(count)});
      }
    }
  }
}

bool SeamLeveling::Solve(double smoothness) {
  const int n = static_cast<int>(vertex_of_.size());
  if (n == 0) return true;
  std::vector<Eigen::Triplet<double>> triplets;
  Eigen::MatrixXd rhs = Eigen::MatrixXd::Zero(n, 3);
  // A squared difference weight * (x_i - x_j - d)^2 in the normal equations.
  const auto add_difference = [&](int i, int j, double weight, const Eigen::Vector3d& d) {
    triplets.emplace_back(i, i, weight);
    triplets.emplace_back(j, j, weight);
    triplets.emplace_back(i, j, -weight);
    triplets.emplace_back(j, i, -weight);
    rhs.row(i) += weight * d.transpose();
    rhs.row(j) -= weight * d.transpose();
  };
  // Seams: (f_a + g_a - f_b - g_b)^2 = (g_a - g_b - (f_b - f_a))^2.
  for (const SeamTerm& term : terms_) add_difference(term.a, term.b, 1.0, term.step.cast<double>());
  // Smoothness along the edges of each labelled face.
  for (size_t f = 0; f < mesh_.faces.size(); ++f) {
    if (labels_[f] < 0) continue;
    for (int k = 0; k < 3; ++k) {
      add_difference(face_variables_[f * 3 + k], face_variables_[f * 3 + (k + 1) % 3], smoothness, Eigen::Vector3d::Zero());
    }
  }
  for (int i = 0; i < n; ++i) triplets.emplace_back(i, i, 1e-4);
  Eigen::SparseMatrix<double> a(n, n);
  a.setFromTriplets(triplets.begin(), triplets.end());
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver(a);
  if (solver.info() != Eigen::Success) return false;
  const Eigen::MatrixXd x = solver.solve(rhs);
  if (solver.info() != Eigen::Success || !x.allFinite()) return false;
  for (int i = 0; i < n; ++i) offsets_[i] = x.row(i).transpose().cast<float>();
  return true;
}

double SeamLeveling::MeanSeamStep(bool with_offsets) const {
  double sum = 0;
  for (const SeamTerm& term : terms_) {
    Eigen::Vector3f step = term.step;
    if (with_offsets) step -= offsets_[term.a] - offsets_[term.b];
    sum += step.cwiseAbs().mean();
  }
  return terms_.empty() ? 0.0 : sum / terms_.size();
}

}  // namespace ibmr
