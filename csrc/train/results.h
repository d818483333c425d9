#pragma once
// What commands derive from a run's checkpoint and keep in its folder: evaluations (metrics_<split>[...].json, with
// the frames' images in eval_images_<split>[...]/ when asked). Each metrics file records its provenance: the split,
// the dataset (folder and fingerprint, and whether it is the one the run trained on), the checkpoint's iteration and
// CRC-32, the command and the time. A result whose checkpoint has changed since is stale: training removes stale
// results when it has written a new checkpoint, and a fresh run (train --force) removes every derived output.
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "data/dataset.h"
#include "train/run_folder.h"

namespace sfgs::train {

struct ResultOrigin {
  data::Split split = data::Split::kTest;
  std::string variant;              // "" for the plain protocol, "fitted_poses" for test-time pose fitting
  std::string dataset;              // the dataset's folder
  std::string dataset_fingerprint;  // data::Dataset::fingerprint()
  bool own_dataset = true;          // the dataset the run trained on (its fingerprint, as read_run_dataset gives it)
  int64_t checkpoint_iteration = 0;
  std::string checkpoint_crc32;  // checkpoint_digest() of the checkpoint evaluated
  std::string command;           // the command line that wrote the result
};

// "metrics_test.json", "metrics_test_fitted_poses.json", and for another dataset than the run's own
// "metrics_test_<fingerprint>.json"; the images' folder likewise ("eval_images_test...").
std::string metrics_file_name(const ResultOrigin& origin);
std::string images_folder_name(const ResultOrigin& origin);

// The CRC-32 of the checkpoint file's bytes, as 8 hex digits: what a result was derived from.
std::string checkpoint_digest(const std::string& checkpoint_file);

// The "provenance" object a metrics file carries (with the time it is written, UTC).
nlohmann::json provenance_json(const ResultOrigin& origin);

// Writes `metrics` with its provenance into the run folder atomically, unless the checkpoint changed since the
// evaluation began (a training writing it meanwhile): then it is an error that says so, and nothing is written.
// Returns the file's path.
std::string write_result(const RunFolder& run, const ResultOrigin& origin, nlohmann::json metrics);

// The metrics files of the run whose checkpoint is not `current` (the run's checkpoint_digest(); "" when it has none),
// or that record none, by name. The caller passes the digest it already has (a checkpoint is a large file to read).
std::vector<std::string> stale_results(const RunFolder& run, const std::string& current);
// Removes the stale metrics files and their images' folders (only the PNG files sfgs wrote there; the folder when
// that empties it). Returns the names removed.
std::vector<std::string> remove_stale_results(const RunFolder& run);
// Removes every metrics file and images folder of the run, as a fresh run on the folder must.
void remove_derived_outputs(const RunFolder& run);

}  // namespace sfgs::train
