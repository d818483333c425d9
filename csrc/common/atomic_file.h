#pragma once
// Files the user keeps are never left half-written: bytes go to a temporary file in the same folder, which is
// flushed to the disk and then renamed over the target in one step (and the folder's entry is flushed too). A
// process killed in between leaves only its temporary, named `<target>.tmp-<pid>[...]`, which the next command
// working in that folder removes.
#include <string>
#include <vector>

namespace sfgs {

// Writes `bytes` to `path` atomically. Refuses to replace an existing file unless `overwrite` is set.
// Throws std::runtime_error naming the file on any failure (a full disk included); nothing is left behind then.
void write_file_atomically(const std::string& path, const std::vector<unsigned char>& bytes, bool overwrite);

// The name a process gives its temporary copy of `path` ("<path>.tmp-<pid>"); `suffix` is appended (a video
// writer needs the container's extension).
std::string temporary_path(const std::string& path, const std::string& suffix = "");

// Flushes `path` (a file written by other means, e.g. a library's encoder) to the disk and moves it to `target`
// atomically, flushing the folder's entry. Throws naming both on failure, and then removes `path`.
void commit_file(const std::string& path, const std::string& target);

// Removes the temporaries (`*.tmp-<pid>*`) in `folder` whose process no longer runs: what a killed run left
// behind. Returns the names removed.
std::vector<std::string> remove_stale_temporaries(const std::string& folder);

}  // namespace sfgs
