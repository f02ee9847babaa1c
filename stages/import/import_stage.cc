// Adapter of the import stage: reads a capture folder, writes images/, sparse/ and
// image_list.txt into the workspace (see import.h for the formats).
#include <spdlog/spdlog.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <opencv2/imgcodecs.hpp>  // the flags; the codecs through image_codecs.h
#include <opencv2/imgproc.hpp>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/capture_info.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/content_hash.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_codecs.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/nerf_formats.h"
#include "pipeline/core/stage_api.h"
#include "stages/import/alpha_composite.h"
#include "stages/import/import.h"
#include "stages/import/transforms_splits.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

const std::vector<std::string> kFormatNames = {"auto",   "folder",     "middlebury", "strecha",
                                               "colmap", "transforms", "llff"};
const std::vector<std::string> kAlphaNames = {"composite", "mask", "ignore"};

// Whether a photo carries an alpha channel, from its PNG header (IHDR colour type 4: grey and
// alpha, 6: RGBA) without decoding it; other formats are decoded (TIFF can hold alpha; JPEG,
// BMP and the PNM formats cannot).
bool FileHasAlpha(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), ::tolower);
  if (ext == ".png") {
    std::ifstream file(path, std::ios::binary);
    char head[26] = {};
    if (!file.read(head, sizeof(head))) return false;
    return head[25] == 4 || head[25] == 6;
  }
  if (ext == ".tif" || ext == ".tiff") return HasAlpha(ReadImageUnchanged(path));
  return false;
}

bool IsImageFile(const fs::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), ::tolower);
  static const std::vector<std::string> kExtensions = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".ppm", ".pgm"};
  return std::find(kExtensions.begin(), kExtensions.end(), ext) != kExtensions.end();
}

std::vector<std::string> ListImages(const std::string& folder) {
  std::vector<std::string> names;
  for (const auto& entry : fs::directory_iterator(folder)) {
    if (entry.is_regular_file() && IsImageFile(entry.path())) names.push_back(entry.path().filename().string());
  }
  std::sort(names.begin(), names.end());
  return names;
}

// Where a folder holds no photos but its subfolders do (a dataset's `images/` beside its
// calibration, as fountain-P11 ships): "; its subfolder images holds 11: use that folder as
// inputs.images (IBMR_IMAGES)", naming the subfolder with the most; "" when none has any.
// A folder that cannot be listed gives no hint (the error it is part of stays the one shown).
std::string SubfolderHint(const std::string& folder) {
  std::string best;
  size_t most = 0;
  try {
    for (const auto& entry : fs::directory_iterator(folder)) {
      if (!entry.is_directory()) continue;
      size_t count = 0;
      for (const auto& file : fs::directory_iterator(entry.path())) count += file.is_regular_file() && IsImageFile(file.path());
      if (count > most || (count == most && count > 0 && entry.path().filename().string() < best)) {
        most = count;
        best = entry.path().filename().string();
      }
    }
  } catch (const fs::filesystem_error&) {
    return "";
  }
  if (most == 0) return "";
  return "; its subfolder " + best + " holds " + std::to_string(most) + ": use that folder as inputs.images (IBMR_IMAGES)";
}

// The size the stages see: decoded as they decode it (ReadImageColor: as stored, EXIF orientation
// not applied).
std::pair<int, int> ImageSize(const std::string& path) {
  const cv::Mat image = ReadImageColor(path);
  return {image.cols, image.rows};
}

// Why a photo of a plain folder cannot be used ("" when it can), and what was converted (added to
// `notes`): every photo is decoded as the stages will decode it.
std::string ScreenPhoto(const std::string& path, AlphaMode alpha, std::string* notes, std::pair<int, int>* size) {
  std::error_code ec;
  const auto bytes = fs::file_size(path, ec);
  if (ec) return "cannot read the file (" + ec.message() + ")";
  if (bytes == 0) return "empty file (0 bytes)";
  cv::Mat raw;
  try {
    raw = DecodeImageFile(path, cv::IMREAD_UNCHANGED);
  } catch (const cv::Exception&) {
  }
  if (raw.empty()) return "not an image OpenCV can decode (corrupt, or another kind of file with an image extension)";
  std::string ext = fs::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), ::tolower);
  if (ext == ".jpg" || ext == ".jpeg") {
    // libjpeg decodes a truncated file with a warning and grey rows at the bottom: refuse it when
    // the end-of-image marker (FF D9) is missing from the last bytes.
    std::ifstream file(path, std::ios::binary);
    const std::streamoff tail = std::min<std::streamoff>(static_cast<std::streamoff>(bytes), 64);
    file.seekg(-tail, std::ios::end);
    std::string end(static_cast<size_t>(tail), '\0');
    file.read(end.data(), tail);
    if (end.find("\xFF\xD9") == std::string::npos) return "truncated JPEG (no end-of-image marker)";
  }
  *size = {raw.cols, raw.rows};  // as ReadImageColor decodes it: orientation is not applied
  std::vector<std::string> converted;
  if (HasAlpha(raw)) {
    converted.push_back(alpha == AlphaMode::kComposite ? "alpha composited on import.background, kept in alpha/"
                        : alpha == AlphaMode::kMask   ? "alpha kept in alpha/, colour as stored"
                                                      : "alpha channel ignored");
  }
  if (raw.channels() == 1) converted.push_back("greyscale read as colour");
  if (raw.depth() == CV_16U) converted.push_back("16-bit samples scaled to 8 bits");
  // Every stage reads photos as stored (as COLMAP does): a rotation the camera asked for in EXIF is
  // not applied, and the camera model describes the stored pixels.
  const int orientation = ExifOrientation(path);
  if (orientation != 1) converted.push_back("EXIF orientation " + std::to_string(orientation) + " ignored: used as stored");
  for (size_t i = 0; i < converted.size(); ++i) *notes += (i ? ", " : "") + converted[i];
  return "";
}

// Hard link when possible (same file system), else a copy under a temporary name, then rename.
void PlaceImage(const fs::path& from, const fs::path& to) {
  const fs::path tmp = to.string() + ".tmp.import";
  std::error_code ec;
  fs::remove(tmp, ec);
  fs::create_hard_link(from, tmp, ec);
  if (ec) fs::copy_file(from, tmp, fs::copy_options::overwrite_existing);
  fs::rename(tmp, to);
}

class ImportStage : public Stage {
 public:
  std::string Name() const override { return "import"; }
  std::string Summary() const override {
    return "Image folder (EXIF focal), Middlebury _par.txt, Strecha .camera, COLMAP model, transforms.json / NeRF's "
           "Blender layout (splits, RGBA) or LLFF into sparse/ and images/";
  }
  // 2: photos screened, max_image_size, transforms/llff; 3: splits, alpha composited
  std::string Version() const override { return "3"; }
  HoldoutRole Role() const override { return HoldoutRole::kAllViews; }

  std::vector<ParamSpec> Parameters() const override {
    return {
        {"source", ParamType::kPath, "\"\"", "Capture folder; empty: the config's inputs.images"},
        {"format", ParamType::kString, "auto", "Source format; auto detects _par.txt, gt_dense_cameras/, cameras.txt",
         kFormatNames},
        {"images", ParamType::kPath, "\"\"", "Image folder for a COLMAP model source; empty: <source>/../images"},
        {"max_image_size", ParamType::kInt, "0",
         "Longest image side kept (px): larger photos are resampled (area averaging) and their cameras scaled; 0: as "
         "they are",
         {}},
        {"llff_downscale", ParamType::kInt, "1", "LLFF: read images_<N>/ (1: images/), cameras scaled to match; >= 1"},
        {"focal_prior", ParamType::kDouble, "1.2", "Focal length without EXIF, times max(width, height); > 0"},
        {"folder_camera_model", ParamType::kString, "SIMPLE_RADIAL", "Camera model for a plain image folder",
         {"SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV"}},
        {"splits", ParamType::kStringList, "[train, test]",
         "transforms: the splits read (Blender layout transforms_<split>.json, nerfstudio *_filenames); train "
         "needed; hold one out with holdout: {split: test}",
         {}},
        {"alpha", ParamType::kString, "composite",
         "photos with alpha: composite (colour over `background`, alpha to alpha/), mask (alpha to alpha/, colour as "
         "stored) or ignore",
         kAlphaNames},
        {"background", ParamType::kString, "white",
         "colour transparent pixels are composited on: white, black or [r, g, b] (0-255); render fills holes with it",
         {},
         /*affects_result=*/true,
         /*list_as_text=*/true},
        {"alpha_premultiplied", ParamType::kBool, "false",
         "the photos' colour is already multiplied by alpha (PNG's is not: straight alpha)", {}},
        {"cameras", ParamType::kString, "\"\"",
         "Plain folder: a COLMAP cameras.txt whose camera every photo takes (calibrate's calibration/cameras.txt; "
         "workspace-relative unless absolute); empty: from EXIF and focal_prior"},
    };
  }

  std::optional<ParamError> CheckParams(const Params& params) const override {
    std::string error;
    if (!ToOptions(params).Check(&error)) return ParamError::FromCheck(error);
    if (params.Int("llff_downscale") < 1) return ParamError{"llff_downscale", "must be >= 1"};
    cv::Vec3b colour;
    if (!ParseBackgroundColor(params.String("background"), &colour, &error)) return ParamError{"background", error};
    for (const std::string& split : params.StringList("splits")) {
      if (split != "train" && split != "val" && split != "test") {
        return ParamError{"splits", "each must be train, val or test, got \"" + split + "\""};
      }
    }
    const int64_t max_size = params.Int("max_image_size");
    if (max_size != 0 && (max_size < 16 || max_size > 100000)) {
      return ParamError{"max_image_size", "must be 0 (keep) or in [16, 100000], got " + std::to_string(max_size)};
    }
    return std::nullopt;
  }

  std::vector<std::string> Inputs(const StageContext& context) const override {
    std::vector<std::string> inputs;
    if (!Source(context).empty()) inputs.push_back(Source(context));
    if (context.params.Has("cameras") && !context.params.String("cameras").empty()) {
      inputs.push_back(context.params.String("cameras"));
    }
    return inputs;
  }
  ModelFolders WritesModel() const override { return {"sparse", "images"}; }
  std::vector<std::string> Outputs(const StageContext&) const override {
    return {"images", "sparse", "image_list.txt", kAlphaFolder, kSplitsFile, kBackgroundFile};
  }

  void Run(StageContext& context) const override {
    const std::string source = Source(context);
    if (source.empty()) throw InputError("import: no source folder; set import.source or inputs.images in the config");
    if (!fs::is_directory(source)) throw InputError("import.source: '" + source + "' is not a folder");
    ImportOptions options = ToOptions(context.params);
    if (options.format == ImportFormat::kAuto) options.format = DetectFormat(source);
    Capture capture = ReadCapture(source, options, context.params, CalibratedCamera(context));
    const size_t resized = LimitImageSize(&capture, static_cast<int>(context.params.Int("max_image_size")));
    const size_t with_alpha = CopyImages(capture, options, context);
    WriteImageSplits(context.workspace, capture.splits);
    // The background the photos show where they were transparent: every model's holes take it.
    std::optional<CaptureBackground> background;
    if (with_alpha > 0 && options.alpha == AlphaMode::kComposite) {
      background = CaptureBackground{options.background, "import.background " + context.params.String("background") +
                                                             " (alpha composited)"};
    }
    WriteCaptureBackground(context.workspace, background);
    if (with_alpha > 0) {
      context.metrics["alpha_images"] = with_alpha;
      context.metrics["alpha"] = context.params.String("alpha");
      spdlog::info("[import] {} photos with alpha: {}{}", with_alpha, context.params.String("alpha"),
                   background ? " on " + context.params.String("background") + ", alpha in alpha/" : "");
    }
    if (!capture.splits.empty()) {
      std::map<std::string, int> counts;
      for (const auto& [name, split] : capture.splits) ++counts[split];
      context.metrics["splits"] = counts;
      std::string text;
      for (const auto& [split, count] : counts) text += (text.empty() ? "" : ", ") + split + " " + std::to_string(count);
      spdlog::info("[import] splits: {} (holdout: {{split: test}} holds the test split out)", text);
    }
    if (resized > 0) {
      context.metrics["resized_images"] = resized;
      spdlog::info("[import] {} images resampled to at most {} px", resized, context.params.Int("max_image_size"));
    }
    WriteSparseModelText(context.workspace.SparseDir(), capture.model);
    // Per-view depth bounds of the capture (LLFF), so that plane_sweep and volume need no range in
    // the config: {"<image>": {"near": z, "far": z}}, z along each camera's axis.
    const std::string bounds_path = context.workspace.SparseDir() + "/depth_bounds.json";
    if (!capture.depth_bounds.empty()) {
      WriteFileAtomic(bounds_path, capture.depth_bounds.dump(2) + "\n");
    } else {
      fs::remove(bounds_path);
    }
    std::string list_text;
    for (const std::string& name : capture.names) list_text += name + "\n";
    WriteFileAtomic(context.workspace.Path("image_list.txt"), list_text);
    const std::string format = kFormatNames[static_cast<int>(options.format)];
    context.metrics["images"] = capture.names.size();
    context.metrics["cameras"] = capture.model.cameras.size();
    context.metrics["posed_images"] = capture.model.images.size();
    context.metrics["format"] = format;
    if (!capture.skipped.empty()) context.metrics["skipped_images"] = capture.skipped;
    if (!capture.converted.empty()) context.metrics["converted_images"] = capture.converted;
    spdlog::info("[import] {} format: {} images, {} posed, {} cameras{}", format, capture.names.size(),
                 capture.model.images.size(), capture.model.cameras.size(),
                 capture.model.images.empty() ? " (no poses: run sfm next)" : "");
  }

 private:
  static ImportOptions ToOptions(const Params& params) {
    ImportOptions options;
    const std::string& format = params.String("format");
    options.format = static_cast<ImportFormat>(std::find(kFormatNames.begin(), kFormatNames.end(), format) - kFormatNames.begin());
    options.focal_prior = params.Double("focal_prior");
    options.folder_camera_model = params.String("folder_camera_model");
    const std::string& alpha = params.String("alpha");
    options.alpha = alpha == "mask" ? AlphaMode::kMask : alpha == "ignore" ? AlphaMode::kIgnore : AlphaMode::kComposite;
    std::string error;
    ParseBackgroundColor(params.String("background"), &options.background, &error);  // checked in CheckParams
    options.alpha_premultiplied = params.Bool("alpha_premultiplied");
    return options;
  }

  static std::string Source(const StageContext& context) {
    if (context.params.Has("source") && !context.params.String("source").empty()) return context.params.String("source");
    auto it = context.inputs.find("images");
    return it != context.inputs.end() ? it->second : "";
  }

  // What a source holds: the model, the image names and the folder they are in.
  struct Capture {
    SparseModel model;
    std::vector<std::string> names;
    std::string image_dir;
    std::map<std::string, cv::Size> resize_to;  // photos resampled on import (max_image_size)
    nlohmann::json skipped = nlohmann::json::object();    // photo -> why it was left out
    nlohmann::json converted = nlohmann::json::object();  // photo -> what reading it converts
    nlohmann::json depth_bounds = nlohmann::json::object();  // LLFF: photo -> {near, far}
    ImageSplits splits;  // transforms: photo -> train / val / test
  };

  Capture ReadCapture(const std::string& source, const ImportOptions& options, const Params& params,
                      const std::optional<Camera>& calibrated) const {
    Capture capture;
    capture.image_dir = source;
    switch (options.format) {
      case ImportFormat::kMiddlebury: capture.model = ReadMiddlebury(source); break;
      case ImportFormat::kStrecha:
        capture.image_dir = (fs::path(source) / "images").string();
        capture.model = ReadStrecha(source, capture.image_dir);
        break;
      case ImportFormat::kTransforms: {
        // nerfstudio / instant-ngp transforms.json, or the Blender layout's transforms_<split>.json,
        // each photo's size read once.
        std::map<std::string, std::pair<int, int>> sizes;
        const auto size_of = [&](const std::string& image) {
          auto it = sizes.find(image);
          if (it != sizes.end()) return it->second;
          const std::string path = source + "/" + image;
          if (!fs::exists(path)) throw InputError(path + ": no such photo");
          return sizes[image] = ImageSize(path);
        };
        SplitCapture read = ReadTransformsCapture(source, params.StringList("splits"), size_of);
        capture.model = std::move(read.model);
        capture.splits = std::move(read.splits);
        break;
      }
      case ImportFormat::kLlff: {
        const int downscale = static_cast<int>(params.Int("llff_downscale"));
        capture.image_dir = (fs::path(source) / (downscale > 1 ? "images_" + std::to_string(downscale) : "images")).string();
        if (!fs::is_directory(capture.image_dir)) {
          throw InputError(capture.image_dir + ": no such folder (import.llff_downscale " + std::to_string(downscale) +
                           " reads images_<N>/; 1 reads images/)");
        }
        const std::string npy = (fs::path(source) / "poses_bounds.npy").string();
        std::vector<std::pair<double, double>> bounds;
        const std::vector<std::string> listed = ListImages(capture.image_dir);
        capture.model = ParsePosesBounds(ReadFile(npy), npy, listed, downscale, &bounds);
        for (size_t i = 0; i < listed.size() && i < bounds.size(); ++i) {
          capture.depth_bounds[listed[i]] = {{"near", bounds[i].first}, {"far", bounds[i].second}};
        }
        for (const auto& [id, image] : capture.model.images) {
          const auto [width, height] = ImageSize(capture.image_dir + "/" + image.name);
          const Camera& camera = capture.model.CameraOf(image);
          if (width != camera.width || height != camera.height) {
            throw InputError(capture.image_dir + "/" + image.name + ": is " + std::to_string(width) + "x" +
                             std::to_string(height) + " but poses_bounds.npy says " + std::to_string(camera.width) + "x" +
                             std::to_string(camera.height) + " at downscale " + std::to_string(downscale));
          }
        }
        break;
      }
      case ImportFormat::kColmap:
        capture.image_dir = params.String("images").empty() ? (fs::path(source).parent_path() / "images").string()
                                                            : params.String("images");
        capture.model = ReadSparseModelText(source);
        break;
      default:
        capture.names = ListImages(source);
        capture.model = ReadFolder(source, &capture.names, options, calibrated, &capture.skipped,
                                   &capture.converted);
        return capture;
    }
    for (int id : capture.model.ImageIdsByName()) capture.names.push_back(capture.model.images.at(id).name);
    return capture;
  }

  SparseModel ReadMiddlebury(const std::string& source) const {
    for (const auto& entry : fs::directory_iterator(source)) {
      const std::string name = entry.path().filename().string();
      if (name.size() > 8 && name.compare(name.size() - 8, 8, "_par.txt") == 0) {
        return ParseMiddleburyPar(ReadFile(entry.path().string()), entry.path().string(),
                                  [&](const std::string& image) { return ImageSize(source + "/" + image); });
      }
    }
    throw InputError(source + ": no *_par.txt file; is this a Middlebury multi-view folder?");
  }

  SparseModel ReadStrecha(const std::string& source, const std::string& image_dir) const {
    SparseModel model;
    for (const std::string& name : ListImages(image_dir)) {
      const fs::path camera_path = fs::path(source) / "gt_dense_cameras" / (name + ".camera");
      if (!fs::exists(camera_path)) {
        spdlog::warn("[import] {}: no camera file {}; image skipped", name, camera_path.string());
        continue;
      }
      Image image;
      Camera camera;
      ParseStrechaCamera(ReadFile(camera_path.string()), camera_path.string(), &camera, &image.cam_from_world);
      camera.camera_id = image.image_id = static_cast<int>(model.images.size()) + 1;
      image.camera_id = camera.camera_id;
      image.name = name;
      model.cameras[camera.camera_id] = camera;
      model.images[image.image_id] = image;
    }
    if (model.images.empty()) throw InputError(source + ": no image of images/ has a gt_dense_cameras/<image>.camera file");
    return model;
  }

  // A plain folder: photos that cannot be used are skipped with a warning naming them and why
  // (empty, not an image, truncated, a byte-identical duplicate of another), conversions are said.
  // The camera of import.cameras (every photo of a plain folder takes it), or nullopt when unset.
  static std::optional<Camera> CalibratedCamera(const StageContext& context) {
    const Params& params = context.params;
    if (!params.Has("cameras") || params.String("cameras").empty()) return std::nullopt;
    const std::string given = params.String("cameras");
    const fs::path file = fs::path(given).is_absolute() ? given : context.workspace.Path(given);
    if (file.filename() != "cameras.txt") {
      throw InputError("import.cameras: '" + file.string() + "' must name a COLMAP cameras.txt (e.g. calibration/cameras.txt)");
    }
    std::map<int, Camera> cameras;
    try {
      cameras = ReadCamerasText(file.parent_path().string());
    } catch (const std::exception& e) {
      throw InputError(std::string("import.cameras: ") + e.what() + "; run calibrate first or fix the path");
    }
    if (cameras.size() != 1) {
      throw InputError("import.cameras: " + file.string() + " holds " + std::to_string(cameras.size()) +
                       " cameras; expected the one camera all photos share");
    }
    return cameras.begin()->second;
  }

  SparseModel ReadFolder(const std::string& source, std::vector<std::string>* names_in_out, const ImportOptions& options,
                         const std::optional<Camera>& calibrated, nlohmann::json* skipped, nlohmann::json* converted) const {
    SparseModel model;
    std::vector<std::string> names;
    std::map<std::string, std::string> first_with_hash;
    std::map<std::string, std::pair<int, int>> sizes;  // decoded once, while screening
    for (const std::string& name : *names_in_out) {
      const std::string path = source + "/" + name;
      std::string notes;
      std::pair<int, int> size;
      std::string reason = ScreenPhoto(path, options.alpha, &notes, &size);
      if (reason.empty()) {
        const std::string hash = HashPath(path);
        const auto [it, fresh] = first_with_hash.emplace(hash, name);
        if (!fresh) reason = "byte-identical duplicate of " + it->second + " (no baseline between the two)";
      }
      if (!reason.empty()) {
        spdlog::warn("[import] {}: skipped: {}", path, reason);
        (*skipped)[name] = reason;
        continue;
      }
      if (!notes.empty()) {
        spdlog::info("[import] {}: {}", path, notes);
        (*converted)[name] = notes;
      }
      names.push_back(name);
      sizes[name] = size;
    }
    *names_in_out = names;
    if (names.empty()) {
      throw InputError(source + ": no usable images (png, jpg, tif, bmp, ppm, pgm) in this folder" +
                       (skipped->empty() ? std::string() : " (" + std::to_string(skipped->size()) + " skipped, see the warnings)") +
                       SubfolderHint(source));
    }
    for (const std::string& name : names) {
      const std::string path = source + "/" + name;
      const auto [width, height] = sizes.at(name);
      Camera camera;
      if (calibrated) {
        if (calibrated->width != width || calibrated->height != height) {
          throw InputError(path + " is " + std::to_string(width) + "x" + std::to_string(height) + " but the camera of " +
                           "import.cameras is " + std::to_string(calibrated->width) + "x" +
                           std::to_string(calibrated->height) + "; photos of another camera or size need their own " +
                           "calibration (or leave import.cameras empty)");
        }
        camera = *calibrated;
      } else {
        camera = FolderCamera(width, height, ExifFocalPixels(path, width, height), options);
      }
      camera.camera_id = static_cast<int>(model.cameras.size()) + 1;
      model.cameras[camera.camera_id] = camera;
    }
    return model;
  }

  // Scales the cameras of images whose longest side exceeds `max_size` (> 0) and records the size
  // their photos must be resampled to; 2D observations scale with them. Returns how many.
  static size_t LimitImageSize(Capture* capture, int max_size) {
    if (max_size <= 0) return 0;
    std::map<std::string, int> camera_of;  // image name -> camera id
    for (const auto& [id, image] : capture->model.images) camera_of[image.name] = image.camera_id;
    if (capture->model.images.empty()) {  // a plain folder: one camera per image, in name order
      for (size_t i = 0; i < capture->names.size(); ++i) camera_of[capture->names[i]] = static_cast<int>(i) + 1;
    }
    std::map<int, double> factor_of;  // camera id -> factor (< 1)
    for (auto& [id, camera] : capture->model.cameras) {
      const int longest = std::max(camera.width, camera.height);
      if (longest <= max_size) continue;
      const double factor = static_cast<double>(max_size) / longest;
      const int old_width = camera.width, old_height = camera.height;
      camera = camera.Scaled(factor);
      factor_of[id] = factor;
      for (auto& [image_id, image] : capture->model.images) {
        if (image.camera_id != id) continue;
        for (Point2D& point : image.points2D) {
          point.xy.x() *= static_cast<double>(camera.width) / old_width;
          point.xy.y() *= static_cast<double>(camera.height) / old_height;
        }
      }
    }
    size_t resized = 0;
    for (const std::string& name : capture->names) {
      const auto it = camera_of.find(name);
      if (it == camera_of.end() || !factor_of.count(it->second)) continue;
      const Camera& camera = capture->model.cameras.at(it->second);
      capture->resize_to[name] = cv::Size(camera.width, camera.height);
      ++resized;
    }
    return resized;
  }

  // Places every photo in images/ (a hard link where it is used as it is) and, for photos with an
  // alpha channel (import.alpha not ignore), writes the alpha to alpha/<name>.png and the colour
  // composited over the background (composite). Returns how many photos had an alpha channel.
  size_t CopyImages(const Capture& capture, const ImportOptions& options, const StageContext& context) const {
    const fs::path target = context.workspace.ImagesDir();
    const fs::path alpha_dir = context.workspace.Path(kAlphaFolder);
    fs::create_directories(target);
    fs::remove_all(alpha_dir);  // an earlier import's alpha would not match these photos
    fs::create_directories(alpha_dir);  // a declared output: empty for photos without alpha
    size_t with_alpha = 0;
    for (const std::string& name : capture.names) {
      const fs::path from = fs::path(capture.image_dir) / name;
      if (!fs::exists(from)) throw InputError(from.string() + ": image named in the camera file is missing");
      fs::create_directories((target / name).parent_path());  // transforms.json paths may hold folders
      const auto resize = capture.resize_to.find(name);
      const bool alpha = options.alpha != AlphaMode::kIgnore && FileHasAlpha(from.string());
      if (resize == capture.resize_to.end() && !alpha) {
        PlaceImage(from, target / name);
        continue;
      }
      cv::Mat image, alpha_image;
      if (alpha) {
        ++with_alpha;
        AlphaComposite composite;
        try {
          composite = CompositeOverBackground(ReadImageUnchanged(from.string()), options.background,
                                              options.alpha_premultiplied);
        } catch (const std::invalid_argument& e) {
          throw InputError(from.string() + ": " + e.what() + "; set import.alpha: ignore to use its colour only");
        }
        image = options.alpha == AlphaMode::kComposite ? composite.bgr : ReadImageColor(from.string());
        alpha_image = composite.alpha;
      } else {
        image = ReadImageColor(from.string());
      }
      if (resize != capture.resize_to.end()) {
        cv::resize(image, image, resize->second, 0, 0, cv::INTER_AREA);
        if (alpha) cv::resize(alpha_image, alpha_image, resize->second, 0, 0, cv::INTER_AREA);
      }
      WriteImage((target / name).string(), image);  // atomic
      if (alpha) {
        const fs::path alpha_path = alpha_dir / (name + ".png");
        fs::create_directories(alpha_path.parent_path());
        WriteImage(alpha_path.string(), alpha_image);
      }
    }
    // Images of an earlier import that are not part of this one would confuse later stages.
    for (const auto& entry : fs::directory_iterator(target)) {
      const std::string name = entry.path().filename().string();
      const bool used = std::any_of(capture.names.begin(), capture.names.end(), [&](const std::string& n) {
        return n == name || n.rfind(name + "/", 0) == 0;  // a file, or the folder of some
      });
      if (!used) fs::remove_all(entry.path());
    }
    return with_alpha;
  }
};

}  // namespace

namespace {

// `ibmr export-transforms WORKSPACE [OUT]`: the workspace's posed model (sfm/sparse/ when sfm
// ran, else sparse/) as a nerfstudio transforms.json (frames "images/<name>", OpenGL camera axes),
// written to OUT (default WORKSPACE/transforms.json) so nerfstudio and instant-ngp read the
// workspace as it is.
int ExportTransformsCommand(const std::vector<std::string>& args) {
  if (args.empty() || args.size() > 2 || args[0] == "--help") {
    std::cout << "usage: ibmr export-transforms WORKSPACE [OUT.json]   (default OUT: WORKSPACE/transforms.json)\n";
    return !args.empty() && args[0] == "--help" ? 0 : 2;
  }
  try {
    Workspace workspace(args[0]);
    if (fs::exists(workspace.Path("sfm/sparse/images.txt"))) workspace.SetModelFolders("sfm/sparse", "images");
    const SparseModel model = ReadSparseModelText(workspace.SparseDir());
    if (model.images.empty()) throw InputError(workspace.SparseDir() + ": no posed image to export");
    const std::string out = args.size() == 2 ? args[1] : workspace.Path("transforms.json");
    WriteFileAtomic(out, WriteTransformsJson(model, "images/"));
    std::cout << "wrote " << out << " (" << model.images.size() << " frames)\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << e.what() << "\n";
    return 1;
  }
}

}  // namespace

void RegisterStage_import(StageRegistry* registry) {
  registry->Add(std::make_unique<ImportStage>());
  registry->AddCommand({"export-transforms", "Write sfm/sparse/ (else sparse/) as a nerfstudio / instant-ngp transforms.json",
                        ExportTransformsCommand});
}

}  // namespace ibmr
