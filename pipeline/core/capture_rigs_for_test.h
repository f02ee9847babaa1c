// Camera rigs for tests of the capture analysis (capture_shape.h): a ring or dome round an
// object, an LLFF-like grid facing a scene, a walk along a facade and an arc of a quarter turn,
// each a SparseModel with sparse points the cameras see.
#pragma once

#include <cmath>
#include <string>

#include "pipeline/core/rigid3.h"
#include "pipeline/core/sparse_model.h"

namespace ibmr::capture_rigs {

inline void AddView(SparseModel* model, const Eigen::Vector3d& eye, const Eigen::Vector3d& target) {
  if (model->cameras.empty()) model->cameras[1] = Camera::Pinhole(64, 48, 60, 60, 32, 24);
  Image image;
  image.image_id = static_cast<int>(model->images.size()) + 1;
  image.camera_id = 1;
  image.name = "v" + std::to_string(100 + image.image_id) + ".png";
  image.cam_from_world = LookAt(eye, target, Eigen::Vector3d(0, 0, 1));
  model->images[image.image_id] = image;
}

// Points on a grid of the plane x = 0..., filling a box about `centre` of half size `half`.
inline void AddPoints(SparseModel* model, const Eigen::Vector3d& centre, const Eigen::Vector3d& half) {
  int64_t id = static_cast<int64_t>(model->points.size()) + 1;
  for (int i = 0; i < 8; ++i) {
    for (int j = 0; j < 8; ++j) {
      for (int k = 0; k < 4; ++k) {
        Point3D point;
        point.xyz = centre + Eigen::Vector3d(half.x() * (i / 3.5 - 1), half.y() * (j / 3.5 - 1), half.z() * (k / 1.5 - 1));
        model->points[id++] = point;
      }
    }
  }
}

// `views` cameras on a circle of radius 3 at height `height` round the origin, looking at it.
inline SparseModel Ring(int views, double height = 0.8) {
  SparseModel model;
  for (int i = 0; i < views; ++i) {
    const double a = 2 * M_PI * i / views;
    AddView(&model, Eigen::Vector3d(3 * std::cos(a), 3 * std::sin(a), height), Eigen::Vector3d::Zero());
  }
  AddPoints(&model, Eigen::Vector3d::Zero(), Eigen::Vector3d(0.5, 0.5, 0.5));
  return model;
}

// A 5 x 4 grid of cameras 1 unit wide facing +y at a scene 4..8 units away, each turned up to
// `turn_deg` towards a different point of it (LLFF captures are hand-held).
inline SparseModel ForwardGrid(double turn_deg = 6) {
  SparseModel model;
  for (int i = 0; i < 5; ++i) {
    for (int j = 0; j < 4; ++j) {
      const Eigen::Vector3d eye(0.25 * i - 0.5, 0, 0.25 * j - 0.375);
      const double t = std::tan(turn_deg * M_PI / 180) * 6;
      const Eigen::Vector3d target(eye.x() + t * ((i % 3) - 1), 6, eye.z() + t * ((j % 3) - 1) * 0.5);
      AddView(&model, eye, target);
    }
  }
  AddPoints(&model, Eigen::Vector3d(0, 6, 0), Eigen::Vector3d(3, 2, 2));
  return model;
}

// 12 cameras along a 10-unit street, 4 units from a facade they face.
inline SparseModel FacadeWalk() {
  SparseModel model;
  for (int i = 0; i < 12; ++i) {
    const Eigen::Vector3d eye(10.0 * i / 11 - 5, 0, 1.5);
    AddView(&model, eye, eye + Eigen::Vector3d(0.3 * std::sin(i), 4, 0));
  }
  AddPoints(&model, Eigen::Vector3d(0, 4.5, 2), Eigen::Vector3d(6, 0.5, 2));
  return model;
}

// 11 cameras on a quarter turn round a monument (fountain-P11's kind of capture).
inline SparseModel QuarterArc() {
  SparseModel model;
  for (int i = 0; i < 11; ++i) {
    const double a = M_PI / 2 * i / 10;
    AddView(&model, Eigen::Vector3d(8 * std::cos(a), 8 * std::sin(a), 1.6), Eigen::Vector3d(0, 0, 1));
  }
  AddPoints(&model, Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(2, 2, 1));
  return model;
}

}  // namespace ibmr::capture_rigs
