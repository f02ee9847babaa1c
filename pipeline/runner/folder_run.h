// `ibmr run FOLDER`: the one command a newcomer needs. The folder is recognised as NeRF's Blender
// layout (transforms_train.json), an LLFF capture (poses_bounds.npy), a capture that brings its
// cameras (transforms.json, a COLMAP model, Strecha's gt_dense_cameras/, a Middlebury _par.txt: the
// photo chain without sfm) or
// a folder of photos; the matching shipped config (configs/blender.yaml, llff.yaml, photos.yaml,
// embedded in the program) is written to the workspace as config.yaml, where the user can edit
// it, and run from there. The workspace defaults to FOLDER.ibmr beside the folder. The run's plan
// (capture.json, Stage::Serves) then leaves out the models the capture cannot use.
#pragma once

#include <string>

namespace ibmr {

struct FolderPlan {
  std::string layout;       // "blender", "llff", "posed" or "photos"
  std::string description;  // "NeRF's Blender layout (transforms_train.json)", ...
  std::string config_name;  // the shipped config it runs: "blender.yaml", ...
  std::string config_text;  // that config, adapted to the layout
};

// What `folder` holds and which chain runs it. Throws InputError naming the folder when it has
// neither photos nor a capture file.
FolderPlan PlanForFolder(const std::string& folder);

// FOLDER.ibmr beside the folder (its trailing slashes ignored).
std::string DefaultWorkspaceFor(const std::string& folder);

// Writes the plan's config to WORKSPACE/config.yaml unless one is there (a config the user edited
// is kept; the log says which) and returns its path; a dry run writes a new one to the temporary
// folder instead. The config reads the folder and workspace from IBMR_IMAGES and IBMR_WORKSPACE,
// which this sets.
std::string PrepareFolderRun(const std::string& folder, const std::string& workspace, const FolderPlan& plan,
                             bool dry_run = false);

}  // namespace ibmr
