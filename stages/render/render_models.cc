// The registry of render models: the one place that lists every kind (render_model.h). Each X(Name)
// names the function `RenderModelKind NameKind()` that the model's file (model_<kind>.cc) defines;
// the order is the order `ibmr stages` and the error message for an unknown entry list them. The
// mesh kind (no keyword: any other entry is a mesh path) may stand anywhere.
#include "stages/render/render_model.h"

// Registering a model is one line here.
#define IBMR_RENDER_MODEL_KINDS(X) \
  X(Plane)                         \
  X(Mesh)                          \
  X(SplatDepth)                    \
  X(SplatDepthMerged)              \
  X(SplatSurfels)                  \
  X(Textured)                      \
  X(Vdtm)                          \
  X(Layers)                        \
  X(Volume)                        \
  X(SplatFit)

namespace ibmr {

#define IBMR_DECLARE_KIND(name) RenderModelKind name##Kind();
IBMR_RENDER_MODEL_KINDS(IBMR_DECLARE_KIND)
#undef IBMR_DECLARE_KIND

const std::vector<RenderModelKind>& RenderModelKinds() {
#define IBMR_LIST_KIND(name) name##Kind(),
  static const std::vector<RenderModelKind> kinds = {IBMR_RENDER_MODEL_KINDS(IBMR_LIST_KIND)};
#undef IBMR_LIST_KIND
  return kinds;
}

}  // namespace ibmr
