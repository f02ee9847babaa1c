// The photographs people actually have, imported from a plain folder by `ibmr run`: each is either
// handled (and the log and the import record say so) or left out with a warning naming the file
// and why; the rest of the folder still imports. Cases: a truncated JPEG, a 0-byte file, a text
// file named .jpg, PNG with alpha, 16-bit PNG, greyscale, mixed sizes, an EXIF orientation tag,
// a byte-identical duplicate, and spaces and non-ASCII characters in the folder and file names.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/image_io.h"
#include "tests/run_command.h"

namespace fs = std::filesystem;

namespace {

cv::Mat Pattern(int width, int height, int type) {
  cv::Mat image(height, width, type);
  cv::randu(image, 0, type == CV_16UC3 ? 65535 : 255);
  return image;
}

std::string Encode(const std::string& ext, const cv::Mat& image) {
  std::vector<uint8_t> bytes;
  cv::imencode(ext, image, bytes);
  return std::string(bytes.begin(), bytes.end());
}

void Write(const fs::path& path, const std::string& bytes) { std::ofstream(path, std::ios::binary) << bytes; }

// A JPEG whose EXIF orientation (tag 0x0112) is 6: stored 40x20, a viewer shows it rotated (20x40).
std::string RotatedJpeg() {
  const std::string jpeg = Encode(".jpg", Pattern(40, 20, CV_8UC3));
  const std::string tiff = std::string("MM\0\x2a\0\0\0\x08", 8) +   // big-endian TIFF, IFD at 8
                           std::string("\0\x01", 2) +                // one entry
                           std::string("\x01\x12\0\x03\0\0\0\x01\0\x06\0\0", 12) +  // orientation 6
                           std::string("\0\0\0\0", 4);               // no next IFD
  const std::string payload = std::string("Exif\0\0", 6) + tiff;
  const size_t length = payload.size() + 2;
  const std::string app1 = std::string("\xFF\xE1", 2) + static_cast<char>(length >> 8) + static_cast<char>(length & 0xFF) + payload;
  return jpeg.substr(0, 2) + app1 + jpeg.substr(2);
}

TEST(BadPhotos, EachIsHandledOrSkippedWithItsName) {
  const fs::path root = fs::temp_directory_path() / ("ibmr_bad_photos_" + std::to_string(::getpid()));
  fs::remove_all(root);
  const fs::path folder = root / "my photos" / "été 2026";
  fs::create_directories(folder);
  const std::string good = Encode(".png", Pattern(64, 48, CV_8UC3));
  Write(folder / "a good.png", good);
  Write(folder / "b copy.png", good);  // byte-identical duplicate
  Write(folder / "c larger é.png", Encode(".png", Pattern(80, 60, CV_8UC3)));
  Write(folder / "d alpha.png", Encode(".png", Pattern(64, 48, CV_8UC4)));
  Write(folder / "e deep.png", Encode(".png", Pattern(64, 48, CV_16UC3)));
  Write(folder / "f grey.png", Encode(".png", Pattern(64, 48, CV_8UC1)));
  Write(folder / "g rotated.jpg", RotatedJpeg());
  const std::string jpeg = Encode(".jpg", Pattern(64, 48, CV_8UC3));
  Write(folder / "h truncated.jpg", jpeg.substr(0, jpeg.size() / 2));
  Write(folder / "i empty.jpg", "");
  Write(folder / "j notes.jpg", "these are my notes, not a photograph\n");
  std::ofstream(root / "c.yaml") << "workspace: ws\ninputs:\n  images: \"my photos/été 2026\"\nstages:\n  - import: {format: folder}\n";

  const auto run = ibmr_e2e::RunCommand(std::string(IBMR_BINARY) + " run '" + (root / "c.yaml").string() + "'");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const fs::path ws = root / "ws";
  nlohmann::json record;
  std::ifstream(ws / "records" / "import.json") >> record;
  const nlohmann::json& metrics = record.at("metrics");

  // Left out, each named with its reason in the log and the record.
  const std::vector<std::pair<std::string, std::string>> skipped = {{"b copy.png", "duplicate of a good.png"},
                                                                    {"h truncated.jpg", "truncated"},
                                                                    {"i empty.jpg", "empty file"},
                                                                    {"j notes.jpg", "not an image"}};
  ASSERT_TRUE(metrics.contains("skipped_images")) << metrics.dump(2);
  EXPECT_EQ(metrics["skipped_images"].size(), skipped.size()) << metrics["skipped_images"].dump(2);
  for (const auto& [name, reason] : skipped) {
    ASSERT_TRUE(metrics["skipped_images"].contains(name)) << name;
    EXPECT_NE(metrics["skipped_images"][name].get<std::string>().find(reason), std::string::npos)
        << name << ": " << metrics["skipped_images"][name];
    EXPECT_NE(run.output.find(name), std::string::npos) << "the log does not name " << name;
    EXPECT_FALSE(fs::exists(ws / "images" / name)) << name;
  }
  // Handled, and said so.
  const std::vector<std::pair<std::string, std::string>> converted = {
      {"d alpha.png", "alpha"}, {"e deep.png", "16-bit"}, {"f grey.png", "greyscale"},
      {"g rotated.jpg", "EXIF orientation 6 ignored"}};
  for (const auto& [name, what] : converted) {
    ASSERT_TRUE(metrics["converted_images"].contains(name)) << metrics.dump(2);
    EXPECT_NE(metrics["converted_images"][name].get<std::string>().find(what), std::string::npos);
  }
  // Every imported photo's camera has the size the stages will decode it at: mixed sizes keep
  // their own cameras, and the EXIF-rotated photo is used as stored (as COLMAP does), 40x20.
  const ibmr::SparseModel model = ibmr::ReadSparseModelText((ws / "sparse").string());
  EXPECT_EQ(metrics["images"].get<int>(), 6);
  std::ifstream list(ws / "image_list.txt");
  std::vector<std::string> names;
  for (std::string line; std::getline(list, line);) names.push_back(line);
  ASSERT_EQ(names.size(), 6u);
  ASSERT_EQ(model.cameras.size(), 6u);
  for (size_t i = 0; i < names.size(); ++i) {
    const cv::Mat image = ibmr::ReadImageColor((ws / "images" / names[i]).string());
    const ibmr::Camera& camera = model.cameras.at(static_cast<int>(i) + 1);
    EXPECT_EQ(camera.width, image.cols) << names[i];
    EXPECT_EQ(camera.height, image.rows) << names[i];
    if (names[i] == "g rotated.jpg") {
      EXPECT_EQ(image.cols, 40);
      EXPECT_EQ(image.rows, 20);
    }
    if (names[i] == "c larger é.png") EXPECT_EQ(camera.width, 80);
  }
  if (!::testing::Test::HasFailure()) fs::remove_all(root);
}

}  // namespace
