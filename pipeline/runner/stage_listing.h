// Text for `ibmr stages`: every stage with its summary, holdout role, inputs, outputs and
// parameters (type, default, one-line doc), the one page that lists every option.
#pragma once

#include <string>

#include "pipeline/core/stage_api.h"

namespace ibmr {

std::string DescribeStages(const StageRegistry& registry);

}  // namespace ibmr
