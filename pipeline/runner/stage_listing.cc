// Formats the stage listing (see stage_listing.h).
#include "pipeline/runner/stage_listing.h"

#include <sstream>

#include "pipeline/runner/config.h"

namespace ibmr {

namespace {
std::string RoleText(HoldoutRole role) {
  switch (role) {
    case HoldoutRole::kAllViews: return "all views";
    case HoldoutRole::kTrainingOnly: return "training views only (held-out views are kept out)";
    case HoldoutRole::kScoring: return "scores held-out views";
  }
  return "";
}

std::string Join(const std::vector<std::string>& items) {
  std::string out;
  for (const auto& item : items) out += (out.empty() ? "" : ", ") + item;
  return out.empty() ? "(none)" : out;
}
}  // namespace

std::string DescribeStages(const StageRegistry& registry) {
  std::ostringstream out;
  for (const std::string& name : registry.Names()) {
    const Stage* stage = registry.Find(name);
    StageContext context;  // default parameters: the declared paths for a typical run
    context.workspace = Workspace(".");
    context.params = DefaultParams(*stage, ".");
    out << name << " (version " << stage->Version() << "): " << stage->Summary() << "\n";
    out << "  views:   " << RoleText(stage->Role()) << "\n";
    out << "  inputs:  " << Join(stage->Inputs(context)) << "\n";
    out << "  outputs: " << Join(stage->Outputs(context)) << "\n";
    const CaptureUse use = stage->Serves();
    out << "  serves:  " << (use.kinds.empty() ? "every capture" : Join(use.kinds) + " captures (" + use.why + ")")
        << (stage->SkippedWithItsInputs() ? "; skipped with a stage it reads from" : "") << "\n";
    out << "  parameters:\n";
    for (const ParamSpec& spec : stage->Parameters()) {
      out << "    " << spec.key << " (" << ParamTypeName(spec.type) << ", default " << spec.default_yaml << ")";
      if (!spec.choices.empty()) out << " one of " << Join(spec.choices);
      if (!spec.affects_result) out << " [resource knob: never makes the stage stale]";
      out << "\n      " << spec.doc << "\n";
    }
    out << "\n";
  }
  for (const StageCommand& command : registry.Commands()) {
    out << "command ibmr " << command.name << ": " << command.help << "\n";
  }
  return out.str();
}

}  // namespace ibmr
