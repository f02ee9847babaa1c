// Binary little-endian PLY for point clouds and triangle meshes (the format COLMAP's
// stereo_fusion, OpenMVS and MeshLab read and write). Reading accepts ascii and binary
// little-endian files with float/double coordinates, uchar colours, and face lists with
// uchar/int counts and int/uint indices; other properties are skipped.
//
// Layout written: header "ply / format binary_little_endian 1.0 / comment ... /
// element vertex N / property float x,y,z [nx,ny,nz] [float radius] [uchar red,green,blue] [float confidence] /
// element face M / property list uchar int vertex_indices / end_header", then the vertex records
// packed, then the faces. Writes are atomic (temporary file, then rename).
#pragma once

#include <string>

#include "pipeline/core/mesh.h"

namespace ibmr {

// All functions throw IoError (pipeline/core/errors.h) naming the file and what is wrong.
void WritePointCloudPly(const std::string& path, const PointCloud& cloud);
PointCloud ReadPointCloudPly(const std::string& path);
void WriteMeshPly(const std::string& path, const TriangleMesh& mesh);
TriangleMesh ReadMeshPly(const std::string& path);

}  // namespace ibmr
