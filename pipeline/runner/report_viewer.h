// The report page's 3D viewer: the workspace's models and cameras, drawn by three.js from
// Debian's libjs-three (three.min.js and examples/js/controls/OrbitControls.js, inlined into the
// page), with the geometry embedded as base64 typed arrays, so that the page opens from disk
// (file:// allows no fetch of local files) and offline.
//
// Models, one button each, the first one available shown on load:
//   textured mesh  texture/mesh.glb (binary glTF as the texture stage writes it: one mesh, one
//                  TRIANGLES primitive per atlas page, POSITION, TEXCOORD_0 and the page's PNG;
//                  node transforms are not applied, the stage writes none)
//   surfel mesh    surfels/mesh.ply (vertex colours)
//   fused points   dense/fused.ply (a subsample of at most max_points)
//   hull           hull/hull.ply
//   volume <ref>   volume/<ref>/: the volume stage's planes as a stack of textured quads, read from
//                  volume.json and plane_<k>.png (see ReadVolumeForViewer below)
// Meshes above max_faces are decimated by vertex clustering (viewer_geometry.h); the page says so.
// A model that cannot be read (a corrupt PLY or GLB) stays in the list with the reason, and the
// page shows it instead of the model; the report is still written.
//
// Cameras (dense/sparse, else sfm/sparse, else sparse: the last model a stage wrote) are drawn as
// small frustums: training views grey, held-out ones (scores/heldout.json "heldout") coloured by
// the best held-out score any model reached on that view, shown on hover. Views that
// dense/stereo/view_agreement.json flags (their depth disagrees with the other views': a likely
// wrong pose, issue 67) are drawn in orange, and the legend and hover name them.
//
// Arrays are little-endian: positions float32 xyz, colours uint8 rgb, texture coordinates
// float32 uv (v up, three.js's default flipY), indices uint32.
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <utility>
#include <vector>

namespace ibmr {

// Where Debian's libjs-three puts what the page inlines.
inline constexpr const char* kThreeJsPath = "/usr/share/javascript/three/three.min.js";
inline constexpr const char* kOrbitControlsPath = "/usr/share/javascript/three/examples/js/controls/OrbitControls.js";

struct ViewerOptions {
  int max_faces = 300000;        // report.max_faces: a mesh with more faces is decimated for the page, > 0
  int max_points = 300000;       // fused points drawn at most (an even subsample), > 0
  int max_texture_size = 2048;   // texels on the longer side of an embedded atlas page, [16, 16384]
  int max_plane_size = 512;      // texels on the longer side of an embedded volume plane, [16, 16384]

  // False with a message naming the option when a value is out of its range.
  bool Check(std::string* error) const;
};

// What the page's viewer gets: `viewer` goes into the page's data (models with their counts,
// decimation, errors and the ids of their arrays; cameras; the scene's up direction and frustum
// size), each array into an element of its own (ViewerArraysHtml), decoded only when its model is shown.
struct ViewerData {
  nlohmann::json viewer;
  std::vector<std::pair<std::string, std::string>> arrays;  // (element id, base64 of the array's bytes)
};

// Gathers the models and cameras of `workspace`; `scores` is scores/heldout.json's contents (an
// empty object when absent), `metric` the held-out mean the report ranks by (photo_psnr). Never
// throws for a model or camera file it cannot read: the entry carries the reason.
ViewerData GatherViewer(const std::string& workspace, const nlohmann::json& scores, const std::string& metric,
                        const ViewerOptions& options);

// One volume folder (volume/<reference>/) as the viewer draws it: its volume.json (the format of
// pipeline/core/plane_volume.h) reads
//   {"width": W, "height": H,                       pixels of every plane image
//    "camera": {"params": [fx, fy, cx, cy]},         the virtual camera (PINHOLE), pixels, COLMAP's
//                                                    convention (top-left pixel's centre at 0.5, 0.5)
//    "cam_from_world": {"qvec": [qw, qx, qy, qz], "tvec": [tx, ty, tz]},   as COLMAP's images.txt
//    "depths": [d_0, d_1, ...]}                      z depth of plane k in the virtual camera
// (other keys are ignored), and plane k's RGBA image is plane_<k>.png (k from 0, zero-padding
// allowed), one per depth. Returns the model entry ("kind": "planes", each plane's four world
// corners, image corners (0,0), (W,0), (W,H), (0,H) at its depth, and its PNG data URI, alpha
// kept, at most max_plane_size texels on a side). Throws IoError naming the file and what is wrong.
nlohmann::json ReadVolumeForViewer(const std::string& folder, const ViewerOptions& options);

// The <script type="application/octet-stream" id="..."> elements holding `data`'s arrays.
std::string ViewerArraysHtml(const ViewerData& data);

// The viewer's page script (report_viewer_script.cc), a <script> element's contents. It defines
// viewerSection(viewer, parent), which draws the section and returns a promise of the page's
// self-check word: "drawn" (the canvas shows the model: pixels other than the background, read
// back from the WebGL canvas with the cameras hidden), "none" (no model in the workspace),
// "blank" (a model was shown but nothing was drawn), "unreadable" (every model failed to load),
// "nowebgl" or "nothree" (no WebGL context, or three.js was not inlined).
extern const char* const kViewerScript;

}  // namespace ibmr
