// The image names of a COLMAP text model (a workspace's sparse/), sorted by name, read once per
// version of its files. The runner asks for them hundreds of times per run: every stage's declared
// inputs and outputs name its views, and every stage context selects the held-out views from them.
// A synthetic 34-view capture's model is 1.2 MB of text; reading and validating it on each of
// about 400 asks took 5 s of a run's bookkeeping before any stage ran (and again after the race).
// A version is the three files' inode, size and modification time: a rewritten model (atomic
// rename) is a new version.
#pragma once

#include <string>
#include <vector>

namespace ibmr {

// What a model folder holds: `readable` when ReadSparseModelText accepts it, then `names` (sorted by
// name, as SparseModel::ImageIdsByName orders them); else `error`, its message. A folder without
// images.txt is not readable and has an empty error.
struct SparseImageNames {
  bool readable = false;
  std::vector<std::string> names;
  std::string error;
};

// Thread-safe; at most a few folders are kept.
SparseImageNames ReadSparseImageNamesCached(const std::string& sparse_dir);

}  // namespace ibmr
