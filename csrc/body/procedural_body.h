#pragma once
// A human body generated in code in the SMPL-X layout, so the demo and the tests run without downloaded files:
// 55 joints in SMPL-X's order and kinematic tree, a T-pose (arms along +-x, palms down, facing +z, y up, metres),
// a closed surface with separate fingers, a mouth that opens with the jaw, two eyeballs, smooth skinning weights,
// ten shape and ten expression directions, UVs, part labels, a mean hand pose with a PCA basis, and the hands cut
// out in the MANO layout with their vertex-id correspondence. It is exactly left/right symmetric. The surface is a
// box-modelled cage smoothed by two Catmull-Clark steps; docs/body_models.md describes the directions.
#include <string>
#include <vector>

#include "body/mano.h"
#include "body/parts.h"
#include "body/smplx.h"

namespace sfgs::body {

struct ProceduralBody {
  SmplxModelData smplx;                       // posedirs undefined (no pose correctives)
  ManoModelData mano_left, mano_right;        // in the body's model space, like the CC0 Anny stand-ins
  HandVertexIds hand_vertex_ids;              // body vertex of each MANO-layout vertex; left i mirrors right i
  at::Tensor face_vertex_ids;                 // (N) sorted body vertices of the head region (a FLAME-region stand-in)
  at::Tensor mirrored_vertices;               // (V) int64: the vertex each vertex becomes under x -> -x
  std::vector<int64_t> mirrored_expressions;  // the expression direction each becomes under x -> -x
};

// Deterministic: every call returns the same body (a few hundred milliseconds).
ProceduralBody make_procedural_body();

// The SMPL-X-layout model of the .npz at `path`, or the built-in procedural body's when the path is empty (how every
// command names its body: synth --body, fit --body, a run's body.smplx).
SmplxModelData smplx_model_or_procedural(const std::string& path);

// Writes the body in the official on-disk formats: procedural_smplx.npz, procedural_mano_{left,right}.npz,
// procedural_MANO_SMPLX_vertex_ids.npz and procedural_face_vertex_ids.npy.
void write_procedural_body(const ProceduralBody& body, const std::string& folder, bool overwrite);

}  // namespace sfgs::body
