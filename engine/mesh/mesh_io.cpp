// Mesh file entry points (dispatch on extension) and the reader machinery they share: the
// bounds-checked cursor, number parsing, node tag maps and the raw-mesh-to-Mesh step.
#include <algorithm>
#include <bit>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdarg>
#include <cstring>
#include <filesystem>
#include <limits>

#include "engine/mesh/mesh_io.h"
#include "engine/mesh/mesh_io_internal.h"

namespace zona {
namespace io_detail {

// ---- numbers and messages ----

bool parse_int(std::string_view token, int64_t& value) {
  if (token.size() > 1 && token[0] == '+' && token[1] != '-' && token[1] != '+')
    token.remove_prefix(1);
  const char* end = token.data() + token.size();
  const auto [ptr, ec] = std::from_chars(token.data(), end, value);
  return ec == std::errc() && ptr == end;
}

bool parse_real(std::string_view token, double& value) {
  // from_chars is locale-independent and exact, but takes no leading '+'.
  if (token.size() > 1 && token[0] == '+' && token[1] != '-' && token[1] != '+')
    token.remove_prefix(1);
  const char* end = token.data() + token.size();
  const auto [ptr, ec] = std::from_chars(token.data(), end, value, std::chars_format::general);
  return ec == std::errc() && ptr == end;
}

std::string excerpt(std::string_view text) {
  constexpr size_t kMax = 32;
  std::string out;
  for (size_t i = 0; i < text.size() && i < kMax; ++i) {
    const unsigned char ch = static_cast<unsigned char>(text[i]);
    out.push_back(ch >= 0x20 && ch < 0x7f ? static_cast<char>(ch) : '?');
  }
  if (text.size() > kMax) out += "...";
  return out;
}

// ---- cursor ----

namespace {
bool is_space(char ch) {
  return ch == ' ' || ch == '\n' || ch == '\t' || ch == '\r' || ch == '\v' || ch == '\f';
}
}  // namespace

bool Cursor::fail(const char* format, ...) {
  if (failed_) return false;  // keep the first error: later ones are consequences
  char text[512];
  va_list args;
  va_start(args, format);
  std::vsnprintf(text, sizeof text, format, args);
  va_end(args);
  for (char* p = text; *p; ++p)
    if (*p == '\n' || *p == '\r') *p = ' ';  // one line, whatever the file held
  error_ = byte_offsets_ ? make_error("%s:byte %zu: %s", name_.c_str(), mark_pos_, text).message
                         : make_error("%s:%zu: %s", name_.c_str(), mark_line_, text).message;
  failed_ = true;
  return false;
}

void Cursor::skip_space() {
  while (pos_ < data_.size() && is_space(data_[pos_])) {
    if (data_[pos_] == '\n') ++line_;
    ++pos_;
  }
}

void Cursor::skip_line() {
  const size_t nl = data_.find('\n', pos_);
  if (nl == std::string_view::npos) {
    pos_ = data_.size();
  } else {
    pos_ = nl + 1;
    ++line_;
  }
}

bool Cursor::end_of_line() {
  if (failed_) return false;
  while (pos_ < data_.size() && (data_[pos_] == ' ' || data_[pos_] == '\t' || data_[pos_] == '\r'))
    ++pos_;
  mark();
  if (pos_ < data_.size() && data_[pos_] == '\n') {
    ++pos_;
    ++line_;
    return true;
  }
  return fail("expected the end of the line");
}

bool Cursor::token(std::string_view& out, const char* what) {
  if (failed_) return false;
  skip_space();
  mark();
  if (pos_ >= data_.size()) return fail("unexpected end of file; expected %s", what);
  const size_t start = pos_;
  while (pos_ < data_.size() && !is_space(data_[pos_])) ++pos_;
  out = data_.substr(start, pos_ - start);
  return true;
}

bool Cursor::keyword(std::string_view expected) {
  const std::string want(expected);
  std::string_view got;
  if (!token(got, want.c_str())) return false;
  if (got != expected) return fail("expected %s, got '%s'", want.c_str(), excerpt(got).c_str());
  return true;
}

std::string_view Cursor::rest_of_line() {
  const size_t start = pos_;
  skip_line();
  size_t end = pos_;
  if (end > start && data_[end - 1] == '\n') --end;
  if (end > start && data_[end - 1] == '\r') --end;
  return data_.substr(start, end - start);
}

bool Cursor::integer(int64_t& value, const char* what, int64_t lo, int64_t hi) {
  std::string_view t;
  return token(t, what) && integer_field(t, value, what, lo, hi);
}

bool Cursor::real(double& value, const char* what) {
  std::string_view t;
  return token(t, what) && real_field(t, value, what);
}

bool Cursor::integer_field(std::string_view t, int64_t& value, const char* what, int64_t lo,
                           int64_t hi) {
  if (failed_) return false;
  if (!parse_int(t, value)) return fail("expected %s, got '%s'", what, excerpt(t).c_str());
  if (value < lo || value > hi)
    return fail("%s %lld out of range [%lld, %lld]", what, static_cast<long long>(value),
                static_cast<long long>(lo), static_cast<long long>(hi));
  return true;
}

bool Cursor::real_field(std::string_view t, double& value, const char* what) {
  if (failed_) return false;
  if (!parse_real(t, value)) return fail("expected %s, got '%s'", what, excerpt(t).c_str());
  if (!std::isfinite(value)) return fail("%s is not finite ('%s')", what, excerpt(t).c_str());
  return true;
}

bool Cursor::record(std::vector<std::string_view>& tokens) {
  tokens.clear();
  while (!failed_ && pos_ < data_.size()) {
    mark();
    size_t eol = data_.find('\n', pos_);
    if (eol == std::string_view::npos) eol = data_.size();
    std::string_view line = data_.substr(pos_, eol - pos_);
    const size_t hash = line.find('#');
    if (hash != std::string_view::npos) line = line.substr(0, hash);
    pos_ = eol < data_.size() ? eol + 1 : eol;
    if (eol < data_.size()) ++line_;
    size_t i = 0;
    while (i < line.size()) {
      while (i < line.size() && (is_space(line[i]) || line[i] == ',')) ++i;
      const size_t start = i;
      while (i < line.size() && !is_space(line[i]) && line[i] != ',') ++i;
      if (i > start) tokens.push_back(line.substr(start, i - start));
    }
    if (!tokens.empty()) return true;
  }
  if (!failed_) mark();
  return false;
}

bool Cursor::need(size_t bytes, const char* what) {
  if (failed_) return false;
  mark();
  if (remaining() < bytes) return fail("unexpected end of file reading %s", what);
  return true;
}

bool Cursor::i32(int32_t& value, const char* what) {
  if (!need(4, what)) return false;
  uint32_t bits;
  std::memcpy(&bits, data_.data() + pos_, 4);
  if (swap_) bits = __builtin_bswap32(bits);
  value = static_cast<int32_t>(bits);
  pos_ += 4;
  return true;
}

bool Cursor::unsigned_field(uint64_t& value, size_t bytes, const char* what) {
  if (!need(bytes, what)) return false;
  if (bytes == 4) {
    uint32_t bits;
    std::memcpy(&bits, data_.data() + pos_, 4);
    value = swap_ ? __builtin_bswap32(bits) : bits;
  } else {
    ZONA_ASSERT(bytes == 8);
    uint64_t bits;
    std::memcpy(&bits, data_.data() + pos_, 8);
    value = swap_ ? __builtin_bswap64(bits) : bits;
  }
  pos_ += bytes;
  return true;
}

bool Cursor::f64(double& value, const char* what) {
  if (!need(8, what)) return false;
  uint64_t bits;
  std::memcpy(&bits, data_.data() + pos_, 8);
  if (swap_) bits = __builtin_bswap64(bits);
  value = std::bit_cast<double>(bits);
  pos_ += 8;
  if (!std::isfinite(value)) return fail("%s is not finite", what);
  return true;
}

bool Cursor::skip_bytes(uint64_t count, uint64_t size, const char* what) {
  if (failed_) return false;
  mark();
  if (size != 0 && count > remaining() / size)
    return fail("%llu x %llu bytes of %s do not fit in the %zu bytes left of the file",
                static_cast<unsigned long long>(count), static_cast<unsigned long long>(size),
                what, remaining());
  pos_ += static_cast<size_t>(count * size);
  return true;
}

bool Cursor::check_count(uint64_t count, uint64_t min_bytes, const char* what) {
  if (failed_) return false;
  if (min_bytes == 0) min_bytes = 1;
  if (count > remaining() / min_bytes)
    return fail("%s %llu cannot fit in the %zu bytes left of the file", what,
                static_cast<unsigned long long>(count), remaining());
  return true;
}

void Cursor::jump_to(size_t offset) {
  offset = std::min(offset, data_.size());
  if (offset <= pos_) return;
  line_ += static_cast<size_t>(std::count(data_.begin() + pos_, data_.begin() + offset, '\n'));
  pos_ = offset;
}

// ---- node tags ----

bool NodeTagMap::add(uint64_t tag) {
  if (contiguous_) {
    if (count_ == 0) {
      first_ = tag;
      ++count_;
      return true;
    }
    if (tag >= first_ && tag - first_ == count_) {
      ++count_;
      return true;
    }
    // Tags stopped following each other: move what we have into the hash map.
    map_.reserve(count_ + 1);
    for (size_t k = 0; k < count_; ++k) map_.emplace(first_ + k, static_cast<int64_t>(k));
    contiguous_ = false;
  }
  if (!map_.emplace(tag, static_cast<int64_t>(count_)).second) return false;
  ++count_;
  return true;
}

int64_t NodeTagMap::find(uint64_t tag) const {
  if (contiguous_)
    return tag >= first_ && tag - first_ < count_ ? static_cast<int64_t>(tag - first_) : -1;
  const auto it = map_.find(tag);
  return it == map_.end() ? -1 : it->second;
}

// ---- files and finishing ----

Result<std::string> read_file(const std::string& path) {
  namespace fs = std::filesystem;
  // Before opening: a FIFO would block the open, a device (/dev/zero) would never end.
  if (Status st = check_regular_file(path); !st) return st.error();
  std::error_code ec;
  FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) return make_error("%s: cannot open: %s", path.c_str(), std::strerror(errno));
  std::string data;
  const std::uintmax_t size = fs::file_size(path, ec);
  if (!ec) data.reserve(static_cast<size_t>(size));  // a hint only: the read decides the size
  char buffer[1 << 16];
  size_t n;
  while ((n = std::fread(buffer, 1, sizeof buffer, f)) > 0) data.append(buffer, n);
  const bool bad = std::ferror(f) != 0;
  std::fclose(f);
  if (bad) return make_error("%s: read error", path.c_str());
  return data;
}

Status write_file(const std::string& path, std::string_view data) {
  FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) return make_error("%s: cannot write: %s", path.c_str(), std::strerror(errno));
  const size_t written = std::fwrite(data.data(), 1, data.size(), f);
  const int err = written == data.size() ? 0 : errno;
  if (std::fclose(f) != 0 || err != 0)
    return make_error("%s: write failed: %s", path.c_str(), std::strerror(err ? err : errno));
  return {};
}

Status check_mesh_for_write(const Mesh& mesh, const std::string& path) {
  const size_t nv = mesh.vertex_count();
  if (nv > static_cast<size_t>(std::numeric_limits<int32_t>::max()))
    return make_error("%s: %zu vertices exceed the int32 index range", path.c_str(), nv);
  if (!mesh.tet_region.empty() && mesh.tet_region.size() != mesh.tet_count())
    return make_error("%s: %zu region tags for %zu tetrahedra", path.c_str(),
                      mesh.tet_region.size(), mesh.tet_count());
  for (size_t t = 0; t < mesh.tet_count(); ++t)
    for (int32_t v : mesh.tets[t])
      if (v < 0 || static_cast<size_t>(v) >= nv)
        return make_error("%s: tetrahedron %zu references vertex %d, out of range [0, %zu)",
                          path.c_str(), t, v, nv);
  return {};
}

void append_real(std::string& out, double value) {
  char buffer[32];
  const auto [ptr, ec] = std::to_chars(buffer, buffer + sizeof buffer, value);
  out.append(buffer, ec == std::errc() ? static_cast<size_t>(ptr - buffer) : 0);
}

void append_int(std::string& out, int64_t value) {
  char buffer[24];
  const auto [ptr, ec] = std::to_chars(buffer, buffer + sizeof buffer, value);
  out.append(buffer, ec == std::errc() ? static_cast<size_t>(ptr - buffer) : 0);
}

namespace {

Status check_scale(const std::string& name, double scale) {
  if (!(std::isfinite(scale) && scale > 0))
    return make_error("%s: scale %g must be positive and finite", name.c_str(), scale);
  return {};
}

// Keeps the points some tetrahedron uses, in file order, scaled; renumbers the tetrahedra.
Result<std::vector<Vec3d>> compact_points(RawMesh& raw, const std::string& name, double scale,
                                          size_t& dropped) {
  const size_t np = raw.points.size();
  std::vector<int32_t> remap(np, -1);
  for (const Tet& t : raw.tets)
    for (int32_t v : t) {
      if (v < 0 || static_cast<size_t>(v) >= np)  // parsers check this; stay safe regardless
        return make_error("%s: tetrahedron references point %d of %zu", name.c_str(), v, np);
      remap[v] = 0;
    }
  std::vector<Vec3d> out;
  int32_t next = 0;
  for (size_t i = 0; i < np; ++i)
    if (remap[i] == 0) remap[i] = next++;
  out.reserve(static_cast<size_t>(next));
  for (size_t i = 0; i < np; ++i) {
    if (remap[i] < 0) continue;
    const Vec3d p = scale * raw.points[i];
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
      return make_error("%s: point %zu overflows when scaled by %g", name.c_str(), i, scale);
    out.push_back(p);
  }
  for (Tet& t : raw.tets)
    for (int32_t& v : t) v = remap[v];
  dropped = np - out.size();
  return out;
}

}  // namespace

Result<Mesh> finish_mesh(RawMesh raw, const std::string& name, const ReadMeshOptions& options,
                         std::vector<std::string>* warnings) {
  if (Status s = check_scale(name, options.scale); !s) return s.error();
  if (raw.tets.empty())
    return make_error("%s: no tetrahedra in the file (%zu points)", name.c_str(),
                      raw.points.size());
  size_t dropped = 0;
  Result<std::vector<Vec3d>> points = compact_points(raw, name, options.scale, dropped);
  if (!points) return points.error();
  Mesh mesh;
  mesh.rest_positions = std::move(points.value());
  mesh.tets = std::move(raw.tets);
  mesh.tet_region = std::move(raw.tet_region);
  mesh.regions = std::move(raw.regions);
  if (warnings) {
    for (std::string& w : raw.warnings) warnings->push_back(std::move(w));
    if (dropped > 0)
      warnings->push_back(name + ": dropped the points no tetrahedron uses (" +
                          std::to_string(dropped) + ")");
  }
  if (Status s = validate_mesh(mesh, name, options.validate, warnings); !s) return s.error();
  return mesh;
}

Result<std::vector<Vec3d>> finish_positions(RawMesh raw, const std::string& name,
                                            const ReadMeshOptions& options) {
  if (Status s = check_scale(name, options.scale); !s) return s.error();
  if (raw.points.empty()) return make_error("%s: no points", name.c_str());
  if (!raw.tets.empty()) {
    size_t dropped = 0;
    return compact_points(raw, name, options.scale, dropped);
  }
  for (size_t i = 0; i < raw.points.size(); ++i) {
    Vec3d& p = raw.points[i];
    p = options.scale * p;
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
      return make_error("%s: point %zu overflows when scaled by %g", name.c_str(), i,
                        options.scale);
  }
  return std::move(raw.points);
}

}  // namespace io_detail

// ---- public entry points ----

namespace {

std::string lower_extension(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  for (char& ch : ext) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
  return ext;
}

// A TetGen mesh is named by its .node; accept the .ele too and find the other beside it.
void tetgen_paths(const std::string& path, std::string& node, std::string& ele) {
  std::filesystem::path p(path);
  node = std::filesystem::path(p).replace_extension(".node").string();
  ele = std::filesystem::path(p).replace_extension(".ele").string();
}

bool file_exists(const std::string& path) {
  std::error_code ec;
  return std::filesystem::exists(path, ec);
}

Result<io_detail::RawMesh> read_raw(const std::string& path, bool positions_only_allowed,
                                    std::string& name) {
  const std::string ext = lower_extension(path);
  name = path;
  if (ext == ".msh") {
    Result<std::string> data = io_detail::read_file(path);
    if (!data) return data.error();
    return io_detail::parse_gmsh(*data, path);
  }
  if (ext == ".node" || ext == ".ele") {
    std::string node_path, ele_path;
    tetgen_paths(path, node_path, ele_path);
    name = node_path;
    Result<std::string> node = io_detail::read_file(node_path);
    if (!node) return node.error();
    if (!file_exists(ele_path)) {
      if (!positions_only_allowed)
        return make_error("%s: no .ele file beside it (%s): a TetGen mesh needs both",
                          node_path.c_str(), ele_path.c_str());
      return io_detail::parse_tetgen(*node, {}, node_path, {});
    }
    Result<std::string> ele = io_detail::read_file(ele_path);
    if (!ele) return ele.error();
    return io_detail::parse_tetgen(*node, *ele, node_path, ele_path);
  }
  if (ext == ".vtu") {
    Result<std::string> data = io_detail::read_file(path);
    if (!data) return data.error();
    // read_positions (positions_only_allowed) wants the deformed configuration of a frame.
    return io_detail::parse_vtu(*data, path, positions_only_allowed);
  }
  return make_error("%s: unknown mesh format '%s' (expected .msh, .node, .ele or .vtu)",
                    path.c_str(),
                    io_detail::excerpt(ext).c_str());
}

}  // namespace

Result<Mesh> read_mesh(const std::string& path, const ReadMeshOptions& options,
                       std::vector<std::string>* warnings) {
  std::string name;
  Result<io_detail::RawMesh> raw = read_raw(path, false, name);
  if (!raw) return raw.error();
  return io_detail::finish_mesh(std::move(raw.value()), name, options, warnings);
}

Result<std::vector<Vec3d>> read_positions(const std::string& path,
                                          const ReadMeshOptions& options) {
  std::string name;
  Result<io_detail::RawMesh> raw = read_raw(path, true, name);
  if (!raw) return raw.error();
  return io_detail::finish_positions(std::move(raw.value()), name, options);
}

Result<Mesh> read_gmsh_from_memory(std::string_view data, const std::string& name,
                                   const ReadMeshOptions& options,
                                   std::vector<std::string>* warnings) {
  Result<io_detail::RawMesh> raw = io_detail::parse_gmsh(data, name);
  if (!raw) return raw.error();
  return io_detail::finish_mesh(std::move(raw.value()), name, options, warnings);
}

Result<Mesh> read_tetgen_from_memory(std::string_view node, std::string_view ele,
                                     const std::string& node_name, const std::string& ele_name,
                                     const ReadMeshOptions& options,
                                     std::vector<std::string>* warnings) {
  // An empty ele_name means "no .ele" to the parser; give it a name in every case.
  Result<io_detail::RawMesh> raw =
      io_detail::parse_tetgen(node, ele, node_name, ele_name.empty() ? "<ele>" : ele_name);
  if (!raw) return raw.error();
  return io_detail::finish_mesh(std::move(raw.value()), node_name, options, warnings);
}

Result<std::vector<Vec3d>> read_tetgen_node_from_memory(std::string_view node,
                                                        const std::string& name,
                                                        const ReadMeshOptions& options) {
  Result<io_detail::RawMesh> raw = io_detail::parse_tetgen(node, {}, name, {});
  if (!raw) return raw.error();
  return io_detail::finish_positions(std::move(raw.value()), name, options);
}

Status write_mesh(const std::string& path, const Mesh& mesh) {
  const std::string ext = lower_extension(path);
  if (ext == ".msh") return write_gmsh41(path, mesh, false);
  if (ext == ".vtu") return write_vtu(path, mesh);
  return make_error("%s: cannot write format '%s' (expected .msh or .vtu)", path.c_str(),
                    io_detail::excerpt(ext).c_str());
}

}  // namespace zona
