#include "io/npz.h"

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>
#include <set>
#include <sstream>
#include <stdexcept>

#include <ATen/Functions.h>
#include <zip.h>

#include "common/atomic_file.h"

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "the .npy reader assumes a little-endian host");

namespace sfgs::io {
namespace {

constexpr char kMagic[] = "\x93NUMPY";
constexpr size_t kMagicSize = 6;
// numpy pads headers so that the data starts on this boundary.
constexpr size_t kHeaderAlignment = 64;
// An .npy header is a short Python dict literal; anything longer is a corrupt length field.
constexpr uint32_t kMaxHeaderLength = 1u << 20;
// zlib's fastest level: body models are mostly zero blocks (unused blend shapes, absent pose correctives); level 1
// writes the procedural body six times faster than numpy's default level 6, for a 4.3 MB instead of a 2.7 MB file.
constexpr zip_uint32_t kDeflateLevel = 1;
// Archive entries written by this module carry this fixed time (1980-01-01), so equal arrays give equal files.
constexpr time_t kFixedEntryTime = 315532800;

const char* const kSupportedDtypes = "float16/32/64, int8/16/32/64, uint8/16/32/64 and bool";

// Where bytes come from: a plain .npy file or one member of a zip archive.
class ByteSource {
 public:
  virtual ~ByteSource() = default;
  virtual uint64_t size() const = 0;
  // Reads exactly n bytes or throws; `what` says which part of the array was being read.
  virtual void read_exact(void* destination, uint64_t n, const char* what) = 0;
  // Called after the last byte: the member's checksum is verified here.
  virtual void finish() = 0;
};

class FileSource final : public ByteSource {
 public:
  explicit FileSource(const std::string& path) : path_(path) {
    namespace fs = std::filesystem;
    std::error_code ec;
    TORCH_CHECK(fs::exists(path, ec), "cannot read '", path, "': the file does not exist");
    TORCH_CHECK(fs::is_regular_file(path, ec), "cannot read '", path, "': not a regular file");
    size_ = fs::file_size(path, ec);
    TORCH_CHECK(!ec, "cannot read '", path, "': ", ec.message());
    file_ = std::fopen(path.c_str(), "rb");
    TORCH_CHECK(file_ != nullptr, "cannot open '", path, "': ", std::strerror(errno));
  }
  ~FileSource() override { std::fclose(file_); }
  uint64_t size() const override { return size_; }
  void read_exact(void* destination, uint64_t n, const char* what) override {
    const size_t got = std::fread(destination, 1, n, file_);
    TORCH_CHECK(got == n, "'", path_, "' ends inside the ", what, " (", got, " of ", n, " bytes)");
  }
  void finish() override {}

 private:
  std::string path_;
  uint64_t size_ = 0;
  std::FILE* file_ = nullptr;
};

class ZipMemberSource final : public ByteSource {
 public:
  ZipMemberSource(zip_t* archive, zip_uint64_t index, uint64_t size, std::string origin)
      : size_(size), origin_(std::move(origin)) {
    file_ = zip_fopen_index(archive, index, 0);
    TORCH_CHECK(file_ != nullptr, "cannot read ", origin_, ": ", zip_strerror(archive));
  }
  ~ZipMemberSource() override { zip_fclose(file_); }
  uint64_t size() const override { return size_; }
  void read_exact(void* destination, uint64_t n, const char* what) override {
    auto* out = static_cast<char*>(destination);
    uint64_t done = 0;
    while (done < n) {
      const zip_int64_t got = zip_fread(file_, out + done, n - done);
      TORCH_CHECK(got >= 0, "cannot read the ", what, " of ", origin_, ": ", zip_file_strerror(file_),
                  " (the archive is damaged)");
      TORCH_CHECK(got > 0, origin_, " ends inside the ", what, " (", done, " of ", n, " bytes)");
      done += static_cast<uint64_t>(got);
    }
  }
  void finish() override {
    // libzip verifies the CRC only when a read reaches the end of the member.
    char extra;
    const zip_int64_t got = zip_fread(file_, &extra, 1);
    TORCH_CHECK(got >= 0, "cannot read ", origin_, ": ", zip_file_strerror(file_), " (the archive is damaged)");
    TORCH_CHECK(got == 0, origin_, " has bytes after its data");
  }

 private:
  uint64_t size_;
  std::string origin_;
  zip_file_t* file_ = nullptr;
};

// ---- header ---------------------------------------------------------------------------------------------------

struct Dtype {
  std::string descr;
  char kind = 0;         // 'f', 'i', 'u' or 'b'
  int64_t itemsize = 0;  // bytes per element in the file
  bool big_endian = false;
  at::ScalarType stored = at::kDouble;  // the tensor's dtype
};

struct Header {
  Dtype dtype;
  bool fortran_order = false;
  std::vector<int64_t> shape;
};

// Parses numpy's header, a Python dict literal such as {'descr': '<f8', 'fortran_order': False, 'shape': (3, 4), }.
class HeaderParser {
 public:
  HeaderParser(const std::string& text, const std::string& origin) : text_(text), origin_(origin) {}

  Header parse() {
    Header header;
    bool has_descr = false, has_order = false, has_shape = false;
    skip_space();
    expect('{');
    while (true) {
      skip_space();
      if (peek() == '}') break;
      const std::string key = parse_string();
      skip_space();
      expect(':');
      skip_space();
      if (key == "descr") {
        TORCH_CHECK(peek() != '[', origin_, " holds a structured array (dtype ", text_.substr(pos_, 40),
                    "...), which is not supported; supported dtypes are ", kSupportedDtypes);
        header.dtype = parse_dtype(parse_string());
        has_descr = true;
      } else if (key == "fortran_order") {
        header.fortran_order = parse_bool();
        has_order = true;
      } else if (key == "shape") {
        header.shape = parse_shape();
        has_shape = true;
      } else {
        fail("unexpected key '" + key + "'");
      }
      skip_space();
      if (peek() == ',') ++pos_;
    }
    if (!has_descr || !has_order || !has_shape) fail("it lacks one of 'descr', 'fortran_order', 'shape'");
    return header;
  }

 private:
  [[noreturn]] void fail(const std::string& why) const {
    TORCH_CHECK(false, origin_, " has a bad .npy header (", why, "): ", text_);
    throw std::logic_error("unreachable");
  }
  char peek() const {
    if (pos_ >= text_.size()) fail("it ends early");
    return text_[pos_];
  }
  void skip_space() {
    while (pos_ < text_.size() && std::isspace(static_cast<unsigned char>(text_[pos_]))) ++pos_;
  }
  void expect(char c) {
    if (peek() != c) fail(std::string("expected '") + c + "'");
    ++pos_;
  }
  std::string parse_string() {
    const char quote = peek();
    if (quote != '\'' && quote != '"') fail("expected a quoted string");
    const size_t end = text_.find(quote, pos_ + 1);
    if (end == std::string::npos) fail("unterminated string");
    std::string value = text_.substr(pos_ + 1, end - pos_ - 1);
    pos_ = end + 1;
    return value;
  }
  bool parse_bool() {
    if (text_.compare(pos_, 4, "True") == 0) {
      pos_ += 4;
      return true;
    }
    if (text_.compare(pos_, 5, "False") == 0) {
      pos_ += 5;
      return false;
    }
    fail("fortran_order must be True or False");
  }
  std::vector<int64_t> parse_shape() {
    std::vector<int64_t> shape;
    expect('(');
    while (true) {
      skip_space();
      if (peek() == ')') break;
      if (!std::isdigit(static_cast<unsigned char>(peek()))) fail("shape entries must be non-negative integers");
      int64_t dim = 0;
      while (std::isdigit(static_cast<unsigned char>(peek()))) {
        if (dim > (int64_t{1} << 50)) fail("a shape entry is too large");
        dim = dim * 10 + (text_[pos_++] - '0');
      }
      if (peek() == 'L') ++pos_;  // Python 2 long literal
      shape.push_back(dim);
      skip_space();
      if (peek() == ',') ++pos_;
    }
    ++pos_;
    return shape;
  }
  Dtype parse_dtype(const std::string& descr) const {
    Dtype d;
    d.descr = descr;
    size_t i = 0;
    if (i < descr.size() && (descr[i] == '<' || descr[i] == '>' || descr[i] == '|' || descr[i] == '=')) {
      d.big_endian = descr[i] == '>';
      ++i;
    }
    TORCH_CHECK(i < descr.size(), origin_, " has an empty dtype");
    d.kind = descr[i++];
    const std::string size = descr.substr(i);
    const bool numeric = !size.empty() && std::all_of(size.begin(), size.end(), [](char c) { return std::isdigit(c); });
    TORCH_CHECK(d.kind != 'O', origin_, " holds Python objects (dtype '", descr,
                "'), which only a pickle can store; save plain numeric arrays instead "
                "(python/tools/convert_mano_pkl.py converts the official pickles)");
    d.itemsize = numeric && size.size() < 3 ? std::stoll(size) : 0;
    const auto supported = [&](char kind, int64_t bytes, at::ScalarType stored) {
      if (d.kind == kind && d.itemsize == bytes) {
        d.stored = stored;
        return true;
      }
      return false;
    };
    const bool ok = supported('f', 2, at::kHalf) || supported('f', 4, at::kFloat) || supported('f', 8, at::kDouble) ||
                    supported('i', 1, at::kChar) || supported('i', 2, at::kShort) || supported('i', 4, at::kInt) ||
                    supported('i', 8, at::kLong) || supported('u', 1, at::kByte) || supported('u', 2, at::kInt) ||
                    supported('u', 4, at::kLong) || supported('u', 8, at::kLong) || supported('b', 1, at::kBool);
    TORCH_CHECK(ok, origin_, " has dtype '", descr, "', which is not supported (supported: ", kSupportedDtypes, ")");
    return d;
  }

  const std::string& text_;
  const std::string& origin_;
  size_t pos_ = 0;
};

template <typename T> T read_little_endian(const unsigned char* bytes, int64_t size) {
  T value = 0;
  for (int64_t b = size - 1; b >= 0; --b) value = static_cast<T>((value << 8) | bytes[b]);
  return value;
}

// Reads one .npy stream: header, then the data straight into the tensor when no conversion is needed.
at::Tensor read_array(ByteSource& source, const std::string& origin) {
  char prefix[kMagicSize + 2];
  TORCH_CHECK(source.size() >= sizeof(prefix), origin, " is not an .npy array (only ", source.size(), " bytes)");
  source.read_exact(prefix, sizeof(prefix), "header");
  TORCH_CHECK(std::memcmp(prefix, kMagic, kMagicSize) == 0, origin,
              " is not an .npy array (it does not start with the \\x93NUMPY magic)");
  const int major = static_cast<unsigned char>(prefix[kMagicSize]);
  TORCH_CHECK(major >= 1 && major <= 3, origin, " has .npy format version ", major, ", expected 1, 2 or 3");
  unsigned char length_bytes[4] = {0, 0, 0, 0};
  const int length_size = major == 1 ? 2 : 4;
  source.read_exact(length_bytes, length_size, "header");
  const auto header_length = read_little_endian<uint32_t>(length_bytes, length_size);
  TORCH_CHECK(header_length <= kMaxHeaderLength && sizeof(prefix) + length_size + header_length <= source.size(),
              origin, " has a bad .npy header (its length field says ", header_length, " bytes)");
  std::string text(header_length, '\0');
  source.read_exact(text.data(), header_length, "header");
  const Header header = HeaderParser(text, origin).parse();

  int64_t count = 1;
  for (int64_t dim : header.shape) {
    TORCH_CHECK(!__builtin_mul_overflow(count, dim, &count), origin, " has an impossible shape ", header.shape);
  }
  int64_t data_bytes = 0;
  TORCH_CHECK(!__builtin_mul_overflow(count, header.dtype.itemsize, &data_bytes), origin, " has an impossible shape ",
              header.shape);
  const uint64_t available = source.size() - sizeof(prefix) - length_size - header_length;
  TORCH_CHECK(available == static_cast<uint64_t>(data_bytes), origin, " holds ", available,
              " bytes of data, but shape ", c10::IntArrayRef(header.shape), " of dtype '", header.dtype.descr,
              "' needs ", data_bytes, " (the file is truncated or damaged)");

  // Fortran-ordered data is the C-ordered array of the reversed shape, transposed.
  std::vector<int64_t> storage_shape = header.shape;
  if (header.fortran_order) std::reverse(storage_shape.begin(), storage_shape.end());
  const Dtype& dt = header.dtype;
  // uint64 is range-checked on its way to int64; everything else of matching size is copied as is.
  const bool direct = !dt.big_endian && at::elementSize(dt.stored) == static_cast<size_t>(dt.itemsize) &&
                      !(dt.kind == 'u' && dt.itemsize == 8);
  at::Tensor result = at::empty(storage_shape, at::TensorOptions().dtype(dt.stored));
  if (direct) {
    if (data_bytes > 0) source.read_exact(result.data_ptr(), data_bytes, "data");
  } else {
    std::vector<unsigned char> raw(data_bytes);
    if (data_bytes > 0) source.read_exact(raw.data(), data_bytes, "data");
    if (dt.big_endian) {
      for (int64_t e = 0; e < count; ++e)
        std::reverse(raw.begin() + e * dt.itemsize, raw.begin() + (e + 1) * dt.itemsize);
    }
    if (dt.kind == 'u' && dt.itemsize == 2) {
      auto* out = result.data_ptr<int32_t>();
      for (int64_t e = 0; e < count; ++e) out[e] = read_little_endian<uint16_t>(&raw[e * 2], 2);
    } else if (dt.kind == 'u' && dt.itemsize >= 4) {
      auto* out = result.data_ptr<int64_t>();
      for (int64_t e = 0; e < count; ++e) {
        const auto value = read_little_endian<uint64_t>(&raw[e * dt.itemsize], dt.itemsize);
        TORCH_CHECK(value <= static_cast<uint64_t>(INT64_MAX), origin, " holds the uint64 value ", value,
                    ", beyond the int64 range this reader widens uint64 to");
        out[e] = static_cast<int64_t>(value);
      }
    } else {
      std::memcpy(result.data_ptr(), raw.data(), data_bytes);
    }
  }
  source.finish();
  if (header.fortran_order && result.dim() > 1) {
    std::vector<int64_t> reverse(result.dim());
    for (int64_t d = 0; d < result.dim(); ++d) reverse[d] = result.dim() - 1 - d;
    result = result.permute(reverse).contiguous();
  }
  return result;
}

std::string archive_error(int code) {
  zip_error_t error;
  zip_error_init_with_code(&error, code);
  std::string message = zip_error_strerror(&error);
  zip_error_fini(&error);
  return message;
}

// ---- writing ----------------------------------------------------------------------------------------------------

std::string descr_of(const at::Tensor& t, const std::string& name) {
  switch (t.scalar_type()) {
    case at::kHalf:
      return "<f2";
    case at::kFloat:
      return "<f4";
    case at::kDouble:
      return "<f8";
    case at::kChar:
      return "|i1";
    case at::kShort:
      return "<i2";
    case at::kInt:
      return "<i4";
    case at::kLong:
      return "<i8";
    case at::kByte:
      return "|u1";
    case at::kBool:
      return "|b1";
    default:
      TORCH_CHECK(false, "cannot write array '", name, "' of dtype ", t.scalar_type(),
                  " (supported: ", kSupportedDtypes, ")");
  }
  return {};
}

std::vector<char> npy_header(const at::Tensor& t, const std::string& name) {
  std::ostringstream dict;
  dict << "{'descr': '" << descr_of(t, name) << "', 'fortran_order': False, 'shape': (";
  for (int64_t d = 0; d < t.dim(); ++d) dict << (d ? ", " : "") << t.size(d);
  dict << (t.dim() == 1 ? ",), }" : "), }");
  std::string text = dict.str();
  const bool long_header = text.size() + 1 + kMagicSize + 4 > 65535;
  const size_t prefix = kMagicSize + 2 + (long_header ? 4 : 2);
  const size_t total = (prefix + text.size() + 1 + kHeaderAlignment - 1) / kHeaderAlignment * kHeaderAlignment;
  text.append(total - prefix - text.size() - 1, ' ');
  text.push_back('\n');
  std::vector<char> header(kMagic, kMagic + kMagicSize);
  header.push_back(static_cast<char>(long_header ? 2 : 1));
  header.push_back(0);
  for (size_t b = 0; b < (long_header ? 4u : 2u); ++b)
    header.push_back(static_cast<char>((text.size() >> (8 * b)) & 0xff));
  header.insert(header.end(), text.begin(), text.end());
  return header;
}

at::Tensor host_contiguous(const at::Tensor& t, const std::string& name) {
  TORCH_CHECK(t.defined(), "cannot write array '", name, "': the tensor is undefined");
  return t.detach().to(at::kCPU).contiguous();
}

void write_bytes(const std::string& path, const std::vector<unsigned char>& bytes, bool overwrite) {
  try {
    write_file_atomically(path, bytes, overwrite);
  } catch (const std::runtime_error& e) {
    TORCH_CHECK(false, e.what());
  }
}

}  // namespace

// ---- NpzArchive -----------------------------------------------------------------------------------------------

NpzArchive::NpzArchive(const std::string& path) : path_(path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  TORCH_CHECK(fs::exists(path, ec), "cannot read '", path, "': the file does not exist");
  TORCH_CHECK(fs::is_regular_file(path, ec), "cannot read '", path, "': not a regular file");
  int code = 0;
  archive_ = zip_open(path.c_str(), ZIP_RDONLY | ZIP_CHECKCONS, &code);
  if (archive_ == nullptr) {
    TORCH_CHECK(code != ZIP_ER_NOZIP, "'", path,
                "' is not an .npz archive (not a zip file); official .pkl models must be converted first with "
                "python/tools/convert_mano_pkl.py");
    TORCH_CHECK(false, "cannot open '", path, "' as an .npz archive: ", archive_error(code));
  }
  const zip_int64_t entries = zip_get_num_entries(archive_, 0);
  for (zip_int64_t i = 0; i < entries; ++i) {
    const char* name = zip_get_name(archive_, static_cast<zip_uint64_t>(i), ZIP_FL_ENC_GUESS);
    TORCH_CHECK(name != nullptr, "cannot list '", path, "': ", zip_strerror(archive_));
    const std::string member(name);
    if (member.size() > 4 && member.compare(member.size() - 4, 4, ".npy") == 0)
      keys_.push_back(member.substr(0, member.size() - 4));
  }
}

NpzArchive::~NpzArchive() {
  if (archive_ != nullptr) zip_discard(archive_);
}

NpzArchive::NpzArchive(NpzArchive&& other) noexcept
    : path_(std::move(other.path_)), keys_(std::move(other.keys_)), archive_(other.archive_) {
  other.archive_ = nullptr;
}

NpzArchive& NpzArchive::operator=(NpzArchive&& other) noexcept {
  if (this != &other) {
    if (archive_ != nullptr) zip_discard(archive_);
    path_ = std::move(other.path_);
    keys_ = std::move(other.keys_);
    archive_ = other.archive_;
    other.archive_ = nullptr;
  }
  return *this;
}

bool NpzArchive::contains(const std::string& key) const {
  return std::find(keys_.begin(), keys_.end(), key) != keys_.end();
}

at::Tensor NpzArchive::read(const std::string& key) const {
  TORCH_CHECK(archive_ != nullptr, "read from a moved-from NpzArchive");
  if (!contains(key)) {
    std::ostringstream listing;
    for (size_t i = 0; i < keys_.size(); ++i) listing << (i ? ", " : "") << keys_[i];
    TORCH_CHECK(false, "'", path_, "' has no array '", key, "' (it holds: ", listing.str(), ")");
  }
  const std::string member = key + ".npy";
  const zip_int64_t index = zip_name_locate(archive_, member.c_str(), 0);
  TORCH_CHECK(index >= 0, "cannot find '", member, "' in '", path_, "': ", zip_strerror(archive_));
  zip_stat_t stat;
  zip_stat_init(&stat);
  TORCH_CHECK(zip_stat_index(archive_, static_cast<zip_uint64_t>(index), 0, &stat) == 0 && (stat.valid & ZIP_STAT_SIZE),
              "cannot read the size of '", member, "' in '", path_, "': ", zip_strerror(archive_));
  const std::string origin = "array '" + key + "' of '" + path_ + "'";
  ZipMemberSource source(archive_, static_cast<zip_uint64_t>(index), stat.size, origin);
  return read_array(source, origin);
}

at::Tensor read_npy(const std::string& path) {
  FileSource source(path);
  return read_array(source, "'" + path + "'");
}

void write_npy(const std::string& path, const at::Tensor& array, bool overwrite) {
  const at::Tensor host = host_contiguous(array, path);
  const std::vector<char> header = npy_header(host, path);
  std::vector<unsigned char> bytes(header.begin(), header.end());
  const auto* data = static_cast<const unsigned char*>(host.data_ptr());
  bytes.insert(bytes.end(), data, data + host.nbytes());
  write_bytes(path, bytes, overwrite);
}

void write_npz(const std::string& path, const std::vector<std::pair<std::string, at::Tensor>>& arrays, bool overwrite,
               NpzCompression compression) {
  TORCH_CHECK(!arrays.empty(), "cannot write '", path, "': an .npz archive needs at least one array");
  std::set<std::string> names;
  std::vector<at::Tensor> hosts;
  std::vector<std::vector<char>> headers;
  for (const auto& [name, tensor] : arrays) {
    TORCH_CHECK(!name.empty() && names.insert(name).second, "cannot write '", path, "': array name '", name,
                "' is empty or repeated");
    hosts.push_back(host_contiguous(tensor, name));
    headers.push_back(npy_header(hosts.back(), name));
  }

  // The archive is assembled in memory, then written atomically like every file sfgs produces.
  zip_error_t error;
  zip_error_init(&error);
  zip_source_t* buffer = zip_source_buffer_create(nullptr, 0, 0, &error);
  TORCH_CHECK(buffer != nullptr, "cannot create '", path, "': ", zip_error_strerror(&error));
  std::unique_ptr<zip_source_t, decltype(&zip_source_free)> buffer_guard(buffer, &zip_source_free);
  std::unique_ptr<zip_t, decltype(&zip_discard)> archive(zip_open_from_source(buffer, ZIP_TRUNCATE, &error),
                                                         &zip_discard);
  TORCH_CHECK(archive != nullptr, "cannot create '", path, "': ", zip_error_strerror(&error));
  zip_source_keep(buffer);  // the archive now owns one reference; the bytes are read back through ours
  for (size_t i = 0; i < arrays.size(); ++i) {
    std::vector<zip_buffer_fragment_t> fragments;
    fragments.push_back({reinterpret_cast<zip_uint8_t*>(headers[i].data()), headers[i].size()});
    if (hosts[i].nbytes() > 0) fragments.push_back({static_cast<zip_uint8_t*>(hosts[i].data_ptr()), hosts[i].nbytes()});
    zip_source_t* member = zip_source_buffer_fragment(archive.get(), fragments.data(), fragments.size(), 0);
    const std::string name = arrays[i].first + ".npy";
    const zip_int64_t index =
        member == nullptr ? -1 : zip_file_add(archive.get(), name.c_str(), member, ZIP_FL_ENC_UTF_8 | ZIP_FL_OVERWRITE);
    if (index < 0 && member != nullptr) zip_source_free(member);
    TORCH_CHECK(index >= 0, "cannot add '", name, "' to '", path, "': ", zip_strerror(archive.get()));
    const auto method = compression == NpzCompression::kDeflate ? ZIP_CM_DEFLATE : ZIP_CM_STORE;
    TORCH_CHECK(zip_set_file_compression(archive.get(), index, method, kDeflateLevel) == 0 &&
                    zip_file_set_mtime(archive.get(), index, kFixedEntryTime, 0) == 0,
                "cannot set up '", name, "' in '", path, "': ", zip_strerror(archive.get()));
  }
  TORCH_CHECK(zip_close(archive.get()) == 0, "cannot write '", path, "': ", zip_strerror(archive.get()));
  archive.release();  // zip_close freed it

  zip_stat_t stat;
  zip_stat_init(&stat);
  TORCH_CHECK(zip_source_open(buffer) == 0 && zip_source_stat(buffer, &stat) == 0 && (stat.valid & ZIP_STAT_SIZE),
              "cannot write '", path, "': ", zip_error_strerror(zip_source_error(buffer)));
  std::vector<unsigned char> bytes(stat.size);
  const zip_int64_t got = zip_source_read(buffer, bytes.data(), bytes.size());
  zip_source_close(buffer);
  TORCH_CHECK(got == static_cast<zip_int64_t>(bytes.size()), "cannot write '", path,
              "': the in-memory archive could not be read back");
  write_bytes(path, bytes, overwrite);
}

}  // namespace sfgs::io
