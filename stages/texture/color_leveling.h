// Photometric consistency of the atlas: per-view exposure gains, then global seam leveling.
//
// Gains (after Brown & Lowe 2007, §6 gain compensation): one gain g_v per view, minimising
//   sum over faces seen by views v, w of (g_v I_v(f) - g_w I_w(f))^2 / sigma_n^2
//   + sum over views of n_v (1 - g_v)^2 / gain_sigma^2,
// where I_v(f) is the face's mean luminance in view v and n_v the number of pair terms of view v
// (so the prior holds the scale however many faces there are). A small dense linear system; the
// gains are then divided by their mean, so the atlas keeps the photos' overall brightness.
//
// Seam leveling (Waechter et al. 2014, §4.2.1; Lempitsky & Ivanov 2007): after the gains, each
// vertex gets one colour offset g_{v,l} per label l of its incident faces, minimising
//   sum over seam vertices v and label pairs (l1, l2) of (f_{v,l1} + g_{v,l1} - f_{v,l2} - g_{v,l2})^2
//   + leveling_smoothness * sum over edges (a, b) of faces labelled l of (g_{a,l} - g_{b,l})^2,
// with f_{v,l2} - f_{v,l1} the colour difference between the views at the vertex: the mean over
// the faces around v that both views see of (face colour in l2 - face colour in l1), after the
// gains (face means over many pixels, not a point sample at the vertex, which on a mesh that is
// off the surface by a pixel reads the background or an edge). The offsets are interpolated across each face
// (barycentric) and added to its texels: the colour steps at the seams vanish and the correction
// spreads smoothly over the patches, which keep their detail. Sparse least squares (Eigen's
// SimplicialLDLT on the normal equations), per channel, with a 1e-4 ridge for vertices the
// terms leave free.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "pipeline/core/mesh.h"
#include "stages/texture/face_visibility.h"

namespace ibmr {

std::vector<double> SolveGains(const FaceObservations& observations, int views, double gain_sigma,
                               double noise_sigma = 10.0);

// The (vertex, label) unknowns of seam leveling for a labelling.
class SeamLeveling {
 public:
  SeamLeveling(const TriangleMesh& mesh, const std::vector<int>& labels);

  // Unknown of corner `k` of face `f` (-1 for unlabelled faces).
  int Variable(size_t face, int k) const { return face_variables_[face * 3 + k]; }
  size_t Variables() const { return vertex_of_.size(); }
  int VertexOf(int variable) const { return vertex_of_[variable]; }
  int LabelOf(int variable) const { return label_of_[variable]; }
  // Unknowns on a seam (a vertex with two or more labels): those whose colours the solve needs.
  const std::vector<int>& SeamVariables() const { return seam_variables_; }
  size_t SeamVertices() const { return seam_vertices_; }

  // The colour differences of the seam terms from the faces' mean colours per view (times the
  // gains); a pair of labels without a face around the vertex that both see is left out.
  void SetColorsFromFaces(const FaceObservations& observations, const std::vector<double>& gains);
  // Solves for the offsets (BGR per unknown); false when the solver failed (offsets stay zero).
  bool Solve(double smoothness);
  const Eigen::Vector3f& Offset(int variable) const { return offsets_[variable]; }
  // Sum over seam vertices and label pairs of the colour step |f1 + g1 - f2 - g2| (mean over
  // channels), with or without the offsets: what the leveling removes.
  double MeanSeamStep(bool with_offsets) const;

 private:
  const TriangleMesh& mesh_;
  const std::vector<int>& labels_;
  std::vector<int> face_variables_;
  std::vector<int> vertex_of_, label_of_;
  std::vector<std::vector<int>> variables_of_vertex_;
  std::vector<int> seam_variables_;
  size_t seam_vertices_ = 0;
  std::vector<std::vector<int>> faces_of_vertex_;
  struct SeamTerm {
    int a, b;             // unknowns (same vertex, two labels)
    Eigen::Vector3f step;  // f_b - f_a
  };
  std::vector<SeamTerm> terms_;
  std::vector<Eigen::Vector3f> offsets_;
};

}  // namespace ibmr
