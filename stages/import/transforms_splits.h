// A NeRF-world capture read with its splits, as people download it:
//  * NeRF's Blender layout: transforms_train.json, transforms_val.json, transforms_test.json in one
//    folder, each naming its frames ("./train/r_0" -> train/r_0.png); every split asked for is read
//    and merged into one model whose image names keep their split's folder, so names stay unique
//    across splits (test/r_0.png and train/r_0.png); a name two splits share is refused. The layout
//    has one image size (NeRF's loader assumes it): a frame of another size is refused, naming it.
//  * nerfstudio's transforms.json, whose optional "train_filenames", "val_filenames" and
//    "test_filenames" lists give the split of each frame (frames in no list count as train).
// Each image's split goes to the workspace's splits.json (capture_info.h), where the holdout policy
// `split: test` finds the views to hold out. Camera conventions: nerf_formats.h.
#pragma once

#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "pipeline/core/capture_info.h"
#include "pipeline/core/sparse_model.h"

namespace ibmr {

struct SplitCapture {
  SparseModel model;               // image ids 1..N in `names` order; identical cameras shared
  std::vector<std::string> names;  // relative to the folder, split by split, each in file order
  ImageSplits splits;              // name -> split; empty for a transforms.json without lists
};

// Reads `folder` (transforms.json when present, else transforms_<split>.json for each of `wanted`,
// which must include "train"). `image_size(relative path)` gives a photo's width and height and
// throws when it cannot be read. Throws IoError / InputError naming the json file, the frame and
// what is wrong (a frame naming a missing photo, a frame without a matrix, a mix of sizes).
SplitCapture ReadTransformsCapture(const std::string& folder, const std::vector<std::string>& wanted,
                                   const std::function<std::pair<int, int>(const std::string&)>& image_size);

}  // namespace ibmr
