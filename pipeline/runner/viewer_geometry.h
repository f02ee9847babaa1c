// Geometry as the report's 3D viewer draws it, and how a large model is made small enough for a
// page: meshes by vertex clustering (Rossignac & Borrel 1993: vertices snapped to the mean of their
// grid cell, faces that collapse dropped), point clouds by an even subsample.
//
// A ViewerMesh's vertices carry a colour (PLY meshes) or a texture coordinate (texture/mesh.glb:
// a point on a patch border is one vertex per patch, each with its UV). Clustering merges the
// vertices without UVs into one per cell; vertices with UVs only move to their cell's mean and
// keep their UV, so a face that survives still samples its own texels.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <vector>

#include "pipeline/core/mesh.h"

namespace ibmr {

struct ViewerMesh {
  std::vector<Eigen::Vector3f> vertices;
  std::vector<Color3u8> colors;          // empty or one per vertex
  std::vector<Eigen::Vector2f> uvs;      // empty or one per vertex: u right, v up, in [0, 1] over its page
  std::vector<Eigen::Vector3i> faces;    // vertex indices
  std::vector<int> face_page;            // empty or one per face: the texture page it samples
};

// `mesh` with at most `max_faces` faces (> 0): returned as it is when within the budget, else
// clustered on a grid about as fine as the budget allows (the cell starts from an estimate from
// the surface area and grows by 15% until the faces fit). Faces that land on the same three cells
// as an earlier face are dropped with the collapsed ones; vertices no face uses are dropped.
ViewerMesh ClusterDecimate(const ViewerMesh& mesh, size_t max_faces);

// The indices of at most `max_points` (> 0) of `count` points, spread evenly over the order they
// come in (every count/max_points-th); all of them when count <= max_points.
std::vector<size_t> EvenSubsample(size_t count, size_t max_points);

}  // namespace ibmr
