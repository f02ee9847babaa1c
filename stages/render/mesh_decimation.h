// Smaller versions of a mesh proxy for model selection (how much model a scene needs): quadric
// error decimation (Garland & Heckbert 1997) with OpenMesh's Decimater, down to a face budget.
// Vertex colours are kept for the vertices that remain; normals are recomputed.
#pragma once

#include <cstddef>

#include "pipeline/core/mesh.h"

namespace ibmr {

// `mesh` decimated towards `max_faces` faces: collapses stop at the budget, but OpenMesh refuses
// those that would flip a face or break the manifold, so the result can keep more faces than
// `max_faces` (the caller warns); a mesh already within the budget is returned as it is. OpenMesh
// refuses non-manifold faces: those are dropped before decimating (counted in *refused when given).
TriangleMesh DecimateMesh(const TriangleMesh& mesh, size_t max_faces, size_t* refused = nullptr);

}  // namespace ibmr
