// Two-view stereo methods on a rectified pair, by name. One stage's two-view method can build on
// another's without reaching into its folder: plane_sweep registers "plane_sweep", layered_stereo
// registers "layered" (which starts from plane_sweep's disparity), and `ibmr stereo-pair --method`
// and the two-view benchmark run any registered method. Methods register when their stage does
// (RegisterStage_<name>), so a program sees the methods of the stages it registered.
#pragma once

#include <functional>
#include <map>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

namespace ibmr {

struct TwoViewOutput {
  cv::Mat disparity;     // CV_32F, the left view's; <= 0 or NaN: no estimate
  nlohmann::json facts;  // what the method wants recorded (counts, timings), an object or null
};

// Options are the method's own, by name (e.g. {"fill": "false"}); a method throws
// std::invalid_argument naming an option it does not know or cannot parse.
using TwoViewOptions = std::map<std::string, std::string>;
using TwoViewMethod =
    std::function<TwoViewOutput(const cv::Mat& left, const cv::Mat& right, int max_disparity, const TwoViewOptions& options)>;

// Registers (or replaces) a method. Thread-safe.
void RegisterTwoViewMethod(const std::string& name, TwoViewMethod method);
// The method, or an empty function when no stage registered that name.
TwoViewMethod FindTwoViewMethod(const std::string& name);
// Registered names, sorted.
std::vector<std::string> TwoViewMethodNames();

}  // namespace ibmr
