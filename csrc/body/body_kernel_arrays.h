#pragma once
// The raw arrays of the body layers' fused CUDA kernels as they take them: torch-free, so nvcc compiles the kernels
// without a CUDA LibTorch. Each has a LibTorch composition as its reference and the path for everything else.
#include <cstdint>

#include "body/constants.h"

namespace sfgs::body {

// KinematicTreeImpl::pose (kinematics.h).
struct KinematicChainArrays {
  const float* rotations;    // (batch, joints, 3, 3) local rotations, row-major
  const float* rest_joints;  // (batch, joints, 3)
  const float* translation;  // (batch, 3): moves the root
  const int32_t* parents;    // (joints): parents[0] = -1, 0 <= parents[j] < j otherwise
  int64_t batch;
  int32_t joints;
  float* posed_joints;         // (batch, joints, 3) out
  float* joint_transforms;     // (batch, joints, 4, 4) out: [R_world | t_world; 0 0 0 1]
  float* skinning_transforms;  // (batch, joints, 4, 4) out: [R_world | t_world - R_world rest_j; 0 0 0 1]
};

// axis_angle_to_matrix (rotations.h).
struct AxisAngleArrays {
  const float* axis_angle;  // (count, 3)
  int64_t count;
  float series_angle;  // kRotationSeriesAngle: below it the coefficients come from their series
  float* matrices;     // (count, 3, 3) out, row-major
};

// vertex_normals (mesh.h).
struct VertexNormalArrays {
  const float* vertices;        // (vertex_count, 3)
  const int64_t* faces;         // (F, 3); a face with a corner outside [0, vertex_count) is skipped
  const int32_t* face_offsets;  // (vertex_count + 1): vertex v's faces are vertex_faces[face_offsets[v] ..
  const int32_t* vertex_faces;  //   face_offsets[v + 1]), in the order they are summed (VertexFaces)
  int64_t vertex_count;
  float min_length;  // kMinNormalLength: shorter sums give a zero normal
  float* normals;    // (vertex_count, 3) out
};

}  // namespace sfgs::body
