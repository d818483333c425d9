#include "prepare/video_metadata.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <optional>
#include <vector>

#include "prepare/constants.h"

namespace sfgs::prepare {
namespace {

constexpr const char* kFocal35mmKey = "com.apple.quicktime.camera.focal_length.35mm_equivalent";
constexpr double kFullFrameDiagonalMm = 43.27;  // sqrt(36^2 + 24^2)
// A movie atom larger than this is not read (its sample tables would be; the metadata is a few hundred bytes).
constexpr uint64_t kMaxMovieAtomBytes = uint64_t(256) << 20;
// The well-known types of a QuickTime metadata value (the `data` atom's type indicator).
constexpr uint32_t kUtf8 = 1, kSignedInteger = 21, kUnsignedInteger = 22, kFloat32 = 23, kFloat64 = 24;

uint64_t big_endian(const unsigned char* p, int bytes) {
  uint64_t v = 0;
  for (int k = 0; k < bytes; ++k) v = (v << 8) | p[k];
  return v;
}

// An atom's size and header length from its first bytes (at least 8, and 16 where `left` allows), `left` bytes being
// all there is from its start to its container's end (a size of 0: the rest); none when the header does not fit or
// the atom overruns its container.
struct Extent {
  uint64_t size = 0, header = 8;
};

std::optional<Extent> extent_of(const unsigned char* at, uint64_t left) {
  if (left < 8) return std::nullopt;
  Extent e{big_endian(at, 4), 8};
  if (e.size == 1) {
    if (left < 16) return std::nullopt;
    e = {big_endian(at + 8, 8), 16};
  } else if (e.size == 0) {
    e.size = left;
  }
  if (e.size < e.header || e.size > left) return std::nullopt;
  return e;
}

// One atom inside [at, end): its type, and where its payload starts and ends; false when it does not fit.
struct Atom {
  char type[5] = {0, 0, 0, 0, 0};
  const unsigned char* payload = nullptr;
  const unsigned char* end = nullptr;
};

bool next_atom(const unsigned char*& at, const unsigned char* end, Atom& atom) {
  const std::optional<Extent> e = extent_of(at, uint64_t(end - at));
  if (!e) return false;
  std::memcpy(atom.type, at + 4, 4);
  atom.payload = at + e->header;
  atom.end = at + e->size;
  at = atom.end;
  return true;
}

bool is(const Atom& a, const char* type) { return std::memcmp(a.type, type, 4) == 0; }

// A `data` atom's value as a number: integers, floats, or the number a text begins with ("26", "50.00mm").
std::optional<double> data_value(const Atom& data) {
  if (data.end - data.payload < 8) return std::nullopt;
  const uint32_t type = uint32_t(big_endian(data.payload, 4)) & 0xffffff;
  const unsigned char* value = data.payload + 8;  // after the type indicator and the locale
  const int64_t bytes = data.end - value;
  if ((type == kSignedInteger || type == kUnsignedInteger) && (bytes == 1 || bytes == 2 || bytes == 4 || bytes == 8)) {
    const uint64_t raw = big_endian(value, int(bytes));
    if (type == kUnsignedInteger) return double(raw);
    const int shift = 64 - 8 * int(bytes);
    return double(int64_t(raw << shift) >> shift);
  }
  if (type == kFloat32 && bytes == 4) {
    const uint32_t raw = uint32_t(big_endian(value, 4));
    float f;
    std::memcpy(&f, &raw, 4);
    return double(f);
  }
  if (type == kFloat64 && bytes == 8) {
    const uint64_t raw = big_endian(value, 8);
    double d;
    std::memcpy(&d, &raw, 8);
    return d;
  }
  if (type == kUtf8 && bytes > 0) {
    const std::string text(reinterpret_cast<const char*>(value), size_t(bytes));
    char* parsed_to = nullptr;
    const double v = std::strtod(text.c_str(), &parsed_to);
    if (parsed_to != text.c_str()) return v;
  }
  return std::nullopt;
}

// The focal item of a `meta` atom's payload: `keys` names the items, `ilst` holds them by their 1-based index.
std::optional<double> focal_in_meta(const unsigned char* begin, const unsigned char* end) {
  // QuickTime's `meta` is a plain container (its first child, `hdlr`, at once); ISO's carries a version and flags.
  if (end - begin >= 8 && std::memcmp(begin + 4, "hdlr", 4) != 0) begin += 4;
  int64_t focal_index = -1;
  std::optional<double> focal;
  for (int pass = 0; pass < 2; ++pass) {  // the keys first, wherever they lie
    const unsigned char* at = begin;
    Atom child;
    while (next_atom(at, end, child)) {
      if (pass == 0 && is(child, "keys") && child.end - child.payload >= 8) {
        const uint64_t count = big_endian(child.payload + 4, 4);
        const unsigned char* entry = child.payload + 8;
        for (uint64_t k = 0; k < count && child.end - entry >= 8; ++k) {
          const uint64_t size = big_endian(entry, 4);
          if (size < 8 || size > uint64_t(child.end - entry)) break;
          const std::string name(reinterpret_cast<const char*>(entry + 8), size_t(size - 8));
          if (name == kFocal35mmKey) focal_index = int64_t(k) + 1;
          entry += size;
        }
      } else if (pass == 1 && is(child, "ilst") && focal_index > 0) {
        const unsigned char* item_at = child.payload;
        Atom item;
        while (next_atom(item_at, child.end, item)) {
          if (int64_t(big_endian(reinterpret_cast<const unsigned char*>(item.type), 4)) != focal_index) continue;
          const unsigned char* data_at = item.payload;
          Atom data;
          while (next_atom(data_at, item.end, data))
            if (is(data, "data") && !focal) focal = data_value(data);
        }
      }
    }
  }
  return focal;
}

// Every `meta` atom under the movie atom (the movie's, its user data's, each track's), first found first.
std::optional<double> focal_in(const unsigned char* begin, const unsigned char* end, int depth) {
  const unsigned char* at = begin;
  Atom atom;
  while (depth < 8 && next_atom(at, end, atom)) {
    std::optional<double> found;
    if (is(atom, "meta"))
      found = focal_in_meta(atom.payload, atom.end);
    else if (is(atom, "trak") || is(atom, "udta") || is(atom, "mdia") || is(atom, "minf"))
      found = focal_in(atom.payload, atom.end, depth + 1);
    if (found) return found;
  }
  return std::nullopt;
}

}  // namespace

std::optional<double> focal_length_35mm(const std::string& path) {
  std::ifstream file(path, std::ios::binary | std::ios::ate);
  if (!file) return std::nullopt;
  const std::streamoff length = file.tellg();
  if (length <= 0) return std::nullopt;
  file.seekg(0);
  // The top-level atoms, by their headers only, until the movie atom; every atom must end within the file, so the
  // reader only ever moves forward.
  uint64_t position = 0;
  for (;;) {
    const uint64_t left = uint64_t(length) - position;
    unsigned char header[16];
    if (!file.read(reinterpret_cast<char*>(header), std::streamsize(std::min<uint64_t>(left, sizeof header))))
      return std::nullopt;
    const std::optional<Extent> e = extent_of(header, left);
    if (!e) return std::nullopt;
    if (std::memcmp(header + 4, "moov", 4) == 0) {
      if (e->size - e->header > kMaxMovieAtomBytes) return std::nullopt;
      std::vector<unsigned char> movie(size_t(e->size - e->header));
      file.seekg(std::streamoff(position + e->header));
      if (!file.read(reinterpret_cast<char*>(movie.data()), std::streamsize(movie.size()))) return std::nullopt;
      const std::optional<double> focal = focal_in(movie.data(), movie.data() + movie.size(), 0);
      if (focal && std::isfinite(*focal) && *focal >= kMin35mmFocal && *focal <= kMax35mmFocal) return focal;
      return std::nullopt;
    }
    position += e->size;
    file.seekg(std::streamoff(position));
    if (!file) return std::nullopt;
  }
}

double focal_pixels_from_35mm(double focal_35mm, int64_t width, int64_t height) {
  return focal_35mm / kFullFrameDiagonalMm * std::hypot(double(width), double(height));
}

}  // namespace sfgs::prepare
