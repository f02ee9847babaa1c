// A synthetic object capture written as people download NeRF's object captures (the "Blender"
// layout of Mildenhall et al., ECCV 2020, supplementary: transforms_train.json,
// transforms_val.json, transforms_test.json beside train/, val/, test/ folders of RGBA PNGs
// r_<i>.png whose object stands on a transparent background). Test data for the import of that
// layout (issue "Captures as people download them"); follows no seed-paper section.
//
// The object is the synthetic ring's star-shaped solid (synth.h, radius about 1, at the origin,
// +z up). Training cameras spread over the upper hemisphere (a golden-angle spiral, elevations 5 to
// 75 degrees), the validation ones on a ring at 20 degrees, the test ones on a ring at 30 degrees
// between the training azimuths, all `radius` from the centre looking at it, as the published
// captures place theirs. Each frame: "file_path" "./<split>/r_<i>" (no extension, as the layout
// writes it), "rotation", and "transform_matrix" camera-to-world in OpenGL camera axes (x right,
// y up, z backwards); "camera_angle_x" at the top. Pixels are straight (not premultiplied) RGBA,
// 8 bits; transparent pixels hold black, as Blender writes them. `degradation` (synth_degradations.h,
// e.g. specular) makes the object harder in the ways real objects are (shiny parts whose colour
// changes with the view), and `thin_parts` adds fine structure (blades a few pixels wide at 800).
#pragma once

#include <cstdint>
#include <string>

#include "stages/synth/synth_degradations.h"

namespace ibmr {

struct BlenderCaptureOptions {
  int size = 800;           // width = height, pixels, in [16, 4096]
  int train = 100;          // views per split: train in [2, 1000], val and test in [0, 1000]
  int val = 100;
  int test = 200;
  int64_t seed = 1;         // the object's shape and texture, >= 0
  int supersample = 3;      // sub-samples per pixel side (alpha in (supersample^2 + 1) levels), in [1, 8]
  double camera_angle_x = 0.6911112070083618;  // horizontal field of view, radians (the layout's usual)
  double radius = -1;       // camera distance to the object's centre, in [2.5, 100]; -1: the object's
                            // bounding sphere spans 3/4 of the field of view (it stays inside every frame)
  SynthDegradation degradation = SynthDegradation::kNone;
  double strength = 0.0;    // in [0, 1]
  int thin_parts = 0;       // thin blades standing out of the object (synth.h), in [0, 200]

  bool Check(std::string* error) const;  // error starts with the option's name
};

struct BlenderCaptureSummary {
  int frames = 0;
  double mean_alpha_coverage = 0;  // mean fraction of pixels with alpha > 0.5
};

// Writes the capture into `folder` (created; existing files of the same names replaced). Throws
// std::invalid_argument for bad options, IoError when a file cannot be written.
BlenderCaptureSummary WriteBlenderCapture(const std::string& folder, const BlenderCaptureOptions& options);

}  // namespace ibmr
