#include "detect/wholebody.h"

#include <ATen/ATen.h>

namespace sfgs::detect {
namespace {

// COCO-WholeBody index -> MediaPipe pose landmark, -1 for none.
constexpr int kBodyAndFeet[23] = {0,  2,  5,  7,  8,        // nose, left eye, right eye, left ear, right ear
                                  11, 12, 13, 14, 15, 16,   // shoulders, elbows, wrists (left, right)
                                  23, 24, 25, 26, 27, 28,   // hips, knees, ankles
                                  31, -1, 29, 32, -1, 30};  // left big toe (foot tip), small toe, heel; right likewise
constexpr int kVisibility = 3;                              // the landmark column scored as COCO's confidence
constexpr int64_t kFaceFirst = 23, kLeftHandFirst = 91, kRightHandFirst = 112, kHandPoints = 21;

// iBUG-68 point k as the mean of face-mesh vertices [k][0] and [k][1] (equal for a single vertex): jaw 17, brows 10,
// nose 9, eyes 12, outer lips 12, inner lips 8 (the correspondence of PeizhiYan/Mediapipe_2_Dlib_Landmarks).
constexpr int kFaceFromMesh[68][2] = {
    {127, 127}, {234, 234}, {93, 93},   {132, 58},  {58, 172},  {136, 136}, {150, 150}, {176, 176}, {152, 152},
    {400, 400}, {379, 379}, {365, 365}, {397, 288}, {361, 361}, {323, 323}, {454, 454}, {356, 356},  // jaw
    {70, 70},   {63, 63},   {105, 105}, {66, 66},   {107, 107}, {336, 336}, {296, 296}, {334, 334}, {293, 293},
    {300, 300},  // brows
    {168, 6},   {197, 195}, {5, 5},     {4, 4},     {75, 75},   {97, 97},   {2, 2},     {326, 326}, {305, 305},  // nose
    {33, 33},   {160, 160}, {158, 158}, {133, 133}, {153, 153}, {144, 144},  // right eye
    {362, 362}, {385, 385}, {387, 387}, {263, 263}, {373, 373}, {380, 380},  // left eye
    {61, 61},   {39, 39},   {37, 37},   {0, 0},     {267, 267}, {269, 269}, {291, 291}, {321, 321}, {314, 314},
    {17, 17},   {84, 84},   {91, 91},                                                               // outer lips
    {78, 78},   {82, 82},   {13, 13},   {312, 312}, {308, 308}, {317, 317}, {14, 14},   {87, 87}};  // inner lips

void put(at::Tensor& out, int64_t k, const at::Tensor& xy, double score) {
  out[k][0] = xy[0];
  out[k][1] = xy[1];
  out[k][2] = score;
}

}  // namespace

at::Tensor wholebody_keypoints(const PoseFrame& pose, const PartLandmarks& face, const PartLandmarks& left_hand,
                               const PartLandmarks& right_hand) {
  at::Tensor out = at::zeros({kWholeBodyKeypoints, 3});
  if (!pose.found) return out;
  const at::Tensor l = pose.landmarks.to(at::kCPU, at::kFloat).contiguous();
  for (int64_t k = 0; k < 23; ++k)
    if (kBodyAndFeet[k] >= 0)
      put(out, k, l[kBodyAndFeet[k]].slice(0, 0, 2), l[kBodyAndFeet[k]][kVisibility].item<double>());
  if (face.found)
    for (int64_t k = 0; k < 68; ++k) {
      const at::Tensor mean =
          0.5 * (face.points[kFaceFromMesh[k][0]].slice(0, 0, 2) + face.points[kFaceFromMesh[k][1]].slice(0, 0, 2));
      put(out, kFaceFirst + k, mean, face.score);
    }
  for (const auto& [hand, first] : {std::pair(&left_hand, kLeftHandFirst), std::pair(&right_hand, kRightHandFirst)})
    if (hand->found)
      for (int64_t k = 0; k < kHandPoints; ++k) put(out, first + k, hand->points[k].slice(0, 0, 2), hand->score);
  return out;
}

}  // namespace sfgs::detect
