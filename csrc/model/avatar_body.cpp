// AvatarBody: the body models an avatar is built from, generated in code or read from the official files.
#include <string>
#include <utility>

#include <ATen/Functions.h>

#include "body/procedural_body.h"
#include "model/avatar.h"

namespace sfgs::model {

AvatarBody AvatarBody::procedural() {
  body::ProceduralBody procedural = body::make_procedural_body();
  AvatarBody out;
  out.smplx = std::move(procedural.smplx);
  out.has_mano = true;
  out.mano_left = std::move(procedural.mano_left);
  out.mano_right = std::move(procedural.mano_right);
  out.hand_vertex_ids = procedural.hand_vertex_ids;
  out.face_vertex_ids = procedural.face_vertex_ids;
  return out;
}

AvatarBody AvatarBody::load(const std::string& smplx_path, const std::string& mano_left_path,
                            const std::string& mano_right_path, const std::string& hand_ids_path,
                            const std::string& face_ids_path) {
  const int given = int(!mano_left_path.empty()) + int(!mano_right_path.empty()) + int(!hand_ids_path.empty());
  TORCH_CHECK(given == 0 || given == 3,
              "AvatarBody::load: the MANO hands need all three of the left model, the right model and the "
              "MANO_SMPLX_vertex_ids file; got left '",
              mano_left_path, "', right '", mano_right_path, "', ids '", hand_ids_path, "'");
  AvatarBody out;
  out.smplx = body::SmplxModelData::load(smplx_path);
  const int64_t vertices = out.smplx.v_template.size(0);
  if (given == 3) {
    out.has_mano = true;
    out.mano_left = body::ManoModelData::load(mano_left_path);
    out.mano_right = body::ManoModelData::load(mano_right_path);
    out.hand_vertex_ids = body::load_hand_vertex_ids(hand_ids_path, vertices);
  }
  if (!face_ids_path.empty()) out.face_vertex_ids = body::load_face_vertex_ids(face_ids_path, vertices);
  return out;
}

}  // namespace sfgs::model
