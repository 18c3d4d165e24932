// VTK XML .vtu reader for the unstructured grids of linear tetrahedra that write_vtu writes:
// one piece, ascii or inline base64 arrays (UInt32 or UInt64 headers), uncompressed,
// little-endian. Anything else (appended or compressed data, other cell types, several pieces)
// is refused with one line naming the file and what is not supported. read_vtu keeps every
// data array as well (the Python module's reader).
//
// Not a general XML parser: the file is scanned tag by tag, with comments, processing
// instructions and unknown elements outside the arrays skipped; array contents are decoded into
// vectors that grow with what the file holds (never reserved from a count the file states).
#include <algorithm>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <optional>
#include <string>
#include <string_view>
#include <tuple>
#include <vector>

#include "engine/mesh/mesh_io_internal.h"

namespace zona::io_detail {
namespace {

constexpr int kVtkTetra = 10;

struct Attribute {
  std::string_view name;
  std::string value;  // entities decoded
};

// One start tag: its name, attributes, and whether it closed itself ("/>").
struct Tag {
  std::string_view name;
  std::vector<Attribute> attributes;
  bool self_closing = false;
  bool closing = false;  // "</name>"
  size_t offset = 0;     // of the '<'
  size_t end = 0;        // one past the '>'

  const std::string* find(std::string_view key) const {
    for (const Attribute& a : attributes)
      if (a.name == key) return &a.value;
    return nullptr;
  }
};

// A decoded array: numbers as doubles (every integer zona writes is far below 2^53, and larger
// ones are refused where they would be indices).
struct Array {
  std::string name;
  std::string type;
  int components = 1;
  std::vector<double> values;
};

class VtuScanner {
 public:
  VtuScanner(std::string_view data, const std::string& name) : data_(data), name_(name) {}

  /// `arrays`, when given, also receives every point, cell and field array as read.
  Result<RawMesh> parse(bool* points_at_rest, std::vector<double>* displacement,
                        VtuFile* arrays = nullptr);

 private:
  // "<file>:<line>: <what>", the line of `offset`.
#if defined(__GNUC__)
  __attribute__((format(printf, 3, 4)))
#endif
  Error fail(size_t offset, const char* format, ...) const {
    offset = std::min(offset, data_.size());
    const size_t line = 1 + static_cast<size_t>(std::count(
                                data_.begin(), data_.begin() + static_cast<std::ptrdiff_t>(offset), '\n'));
    char text[400];
    va_list args;
    va_start(args, format);
    std::vsnprintf(text, sizeof text, format, args);
    va_end(args);
    for (char* p = text; *p; ++p)
      if (*p == '\n' || *p == '\r') *p = ' ';
    return make_error("%s:%zu: %s", name_.c_str(), line, text);
  }

  Result<std::optional<Tag>> next_tag();
  Result<Array> read_array(const Tag& tag);
  Status decode_ascii(std::string_view text, size_t offset, Array& array) const;
  Status decode_binary(std::string_view text, size_t offset, Array& array) const;

  std::string_view data_;
  const std::string& name_;
  size_t pos_ = 0;
  bool header_uint64_ = true;
};

bool is_space(char ch) { return ch == ' ' || ch == '\n' || ch == '\t' || ch == '\r'; }

std::string decode_entities(std::string_view s) {
  std::string out;
  for (size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '&') {
      static constexpr std::pair<std::string_view, char> kEntities[] = {
          {"&amp;", '&'}, {"&lt;", '<'}, {"&gt;", '>'}, {"&quot;", '"'}, {"&apos;", '\''}};
      bool done = false;
      for (const auto& [entity, ch] : kEntities)
        if (s.substr(i, entity.size()) == entity) {
          out.push_back(ch);
          i += entity.size() - 1;
          done = true;
          break;
        }
      if (done) continue;
    }
    out.push_back(s[i]);
  }
  return out;
}

Result<std::optional<Tag>> VtuScanner::next_tag() {
  while (true) {
    const size_t lt = data_.find('<', pos_);
    if (lt == std::string_view::npos) {
      pos_ = data_.size();
      return std::optional<Tag>{};
    }
    std::string_view rest = data_.substr(lt);
    // Comments, processing instructions and declarations are skipped whole.
    if (rest.substr(0, 4) == "<!--") {
      const size_t close = data_.find("-->", lt + 4);
      if (close == std::string_view::npos) return fail(lt, "unterminated XML comment");
      pos_ = close + 3;
      continue;
    }
    if (rest.substr(0, 2) == "<?" || rest.substr(0, 2) == "<!") {
      const size_t close = data_.find('>', lt);
      if (close == std::string_view::npos) return fail(lt, "unterminated XML declaration");
      pos_ = close + 1;
      continue;
    }
    Tag tag;
    tag.offset = lt;
    size_t i = lt + 1;
    if (i < data_.size() && data_[i] == '/') {
      tag.closing = true;
      ++i;
    }
    const size_t name_start = i;
    while (i < data_.size() && !is_space(data_[i]) && data_[i] != '>' && data_[i] != '/') ++i;
    tag.name = data_.substr(name_start, i - name_start);
    if (tag.name.empty()) return fail(lt, "malformed XML tag");
    // Attributes: name="value" or name='value'.
    while (true) {
      while (i < data_.size() && is_space(data_[i])) ++i;
      if (i >= data_.size()) return fail(lt, "unterminated XML tag <%s", excerpt(tag.name).c_str());
      if (data_[i] == '>') {
        ++i;
        break;
      }
      if (data_[i] == '/' && i + 1 < data_.size() && data_[i + 1] == '>') {
        tag.self_closing = true;
        i += 2;
        break;
      }
      const size_t a = i;
      while (i < data_.size() && data_[i] != '=' && !is_space(data_[i]) && data_[i] != '>') ++i;
      const std::string_view key = data_.substr(a, i - a);
      while (i < data_.size() && is_space(data_[i])) ++i;
      if (key.empty() || i >= data_.size() || data_[i] != '=')
        return fail(i, "malformed attribute in <%s>", excerpt(tag.name).c_str());
      ++i;
      while (i < data_.size() && is_space(data_[i])) ++i;
      if (i >= data_.size() || (data_[i] != '"' && data_[i] != '\''))
        return fail(i, "attribute %s of <%s> has no quoted value", excerpt(key).c_str(),
                    excerpt(tag.name).c_str());
      const char quote = data_[i++];
      const size_t close = data_.find(quote, i);
      if (close == std::string_view::npos)
        return fail(i, "unterminated attribute %s", excerpt(key).c_str());
      tag.attributes.push_back({key, decode_entities(data_.substr(i, close - i))});
      i = close + 1;
    }
    tag.end = i;
    pos_ = i;
    return std::optional<Tag>{std::move(tag)};
  }
}

Status VtuScanner::decode_ascii(std::string_view text, size_t offset, Array& array) const {
  const bool real = array.type == "Float32" || array.type == "Float64";
  size_t i = 0;
  while (true) {
    while (i < text.size() && is_space(text[i])) ++i;
    if (i >= text.size()) break;
    const size_t start = i;
    while (i < text.size() && !is_space(text[i])) ++i;
    const std::string_view token = text.substr(start, i - start);
    if (real) {
      double v = 0;
      if (!parse_real(token, v))
        return fail(offset + start, "array '%s': expected a number, got '%s'",
                    excerpt(array.name).c_str(), excerpt(token).c_str());
      array.values.push_back(v);
    } else {
      int64_t v = 0;
      if (!parse_int(token, v))
        return fail(offset + start, "array '%s': expected an integer, got '%s'",
                    excerpt(array.name).c_str(), excerpt(token).c_str());
      array.values.push_back(static_cast<double>(v));
    }
  }
  return {};
}

int base64_value(char ch) {
  if (ch >= 'A' && ch <= 'Z') return ch - 'A';
  if (ch >= 'a' && ch <= 'z') return ch - 'a' + 26;
  if (ch >= '0' && ch <= '9') return ch - '0' + 52;
  if (ch == '+') return 62;
  if (ch == '/') return 63;
  return -1;
}

// Bytes per value of a VTK type name, 0 for types this reader does not know.
size_t type_size(std::string_view type) {
  if (type == "Float64" || type == "Int64" || type == "UInt64") return 8;
  if (type == "Float32" || type == "Int32" || type == "UInt32") return 4;
  if (type == "Int16" || type == "UInt16") return 2;
  if (type == "Int8" || type == "UInt8") return 1;
  return 0;
}

double load_value(const unsigned char* p, std::string_view type) {
  auto get = [p]<class T>(T) {
    T v;
    std::memcpy(&v, p, sizeof v);
    return static_cast<double>(v);
  };
  if (type == "Float64") return get(double{});
  if (type == "Float32") return get(float{});
  if (type == "Int64") return get(int64_t{});
  if (type == "UInt64") return get(uint64_t{});
  if (type == "Int32") return get(int32_t{});
  if (type == "UInt32") return get(uint32_t{});
  if (type == "Int16") return get(int16_t{});
  if (type == "UInt16") return get(uint16_t{});
  if (type == "Int8") return get(int8_t{});
  return get(uint8_t{});
}

Status VtuScanner::decode_binary(std::string_view text, size_t offset, Array& array) const {
  // Base64 of one stream: the byte count (UInt64 or UInt32 header), then the raw values.
  std::string raw;
  uint32_t acc = 0;
  int bits = 0;
  bool padding = false;
  for (size_t i = 0; i < text.size(); ++i) {
    const char ch = text[i];
    if (is_space(ch)) continue;
    if (ch == '=') {
      padding = true;
      continue;
    }
    const int v = base64_value(ch);
    if (v < 0 || padding)
      return fail(offset + i, "array '%s': invalid base64 data", excerpt(array.name).c_str());
    acc = (acc << 6) | static_cast<uint32_t>(v);
    bits += 6;
    if (bits >= 8) {
      bits -= 8;
      raw.push_back(static_cast<char>((acc >> bits) & 0xffu));
    }
  }
  const size_t header = header_uint64_ ? 8 : 4;
  if (raw.size() < header)
    return fail(offset, "array '%s': binary data shorter than its header",
                excerpt(array.name).c_str());
  uint64_t bytes = 0;
  if (header == 8) {
    std::memcpy(&bytes, raw.data(), 8);
  } else {
    uint32_t b32 = 0;
    std::memcpy(&b32, raw.data(), 4);
    bytes = b32;
  }
  const size_t size = type_size(array.type);
  if (bytes > raw.size() - header)
    return fail(offset, "array '%s': header says %llu bytes, the data holds %zu",
                excerpt(array.name).c_str(), static_cast<unsigned long long>(bytes),
                raw.size() - header);
  if (bytes % size != 0)
    return fail(offset, "array '%s': %llu bytes is not a whole number of %s values",
                excerpt(array.name).c_str(), static_cast<unsigned long long>(bytes),
                array.type.c_str());
  const auto* p = reinterpret_cast<const unsigned char*>(raw.data()) + header;
  for (uint64_t k = 0; k < bytes / size; ++k) array.values.push_back(load_value(p + k * size, array.type));
  return {};
}

Result<Array> VtuScanner::read_array(const Tag& tag) {
  Array array;
  if (const std::string* n = tag.find("Name")) array.name = *n;
  const std::string* type = tag.find("type");
  if (!type || type_size(*type) == 0)
    return fail(tag.offset, "array '%s': type '%s' is not supported (numeric types only)",
                excerpt(array.name).c_str(), type ? excerpt(*type).c_str() : "");
  array.type = *type;
  if (const std::string* c = tag.find("NumberOfComponents")) {
    int64_t n = 0;
    if (!parse_int(*c, n) || n < 1 || n > 64)
      return fail(tag.offset, "array '%s': NumberOfComponents '%s' is not in [1, 64]",
                  excerpt(array.name).c_str(), excerpt(*c).c_str());
    array.components = static_cast<int>(n);
  }
  const std::string* format = tag.find("format");
  const std::string fmt = format ? *format : "ascii";
  if (fmt == "appended")
    return fail(tag.offset, "array '%s': appended data is not supported (zona reads inline "
                "ascii or base64 arrays, as it writes them)", excerpt(array.name).c_str());
  if (fmt != "ascii" && fmt != "binary")
    return fail(tag.offset, "array '%s': format '%s' is not supported",
                excerpt(array.name).c_str(), excerpt(fmt).c_str());
  if (tag.self_closing) return array;
  const size_t close = data_.find("</DataArray>", tag.end);
  if (close == std::string_view::npos)
    return fail(tag.offset, "array '%s' has no </DataArray>", excerpt(array.name).c_str());
  const std::string_view text = data_.substr(tag.end, close - tag.end);
  if (text.find('<') != std::string_view::npos)
    return fail(tag.end + text.find('<'), "array '%s' holds XML elements; not supported",
                excerpt(array.name).c_str());
  if (Status s = fmt == "ascii" ? decode_ascii(text, tag.end, array)
                                : decode_binary(text, tag.end, array);
      !s)
    return s.error();
  if (array.values.size() % static_cast<size_t>(array.components) != 0)
    return fail(tag.offset, "array '%s': %zu values are not a whole number of %d-component tuples",
                excerpt(array.name).c_str(), array.values.size(), array.components);
  pos_ = close + std::strlen("</DataArray>");
  return array;
}

// A non-negative integer count attribute.
bool count_attribute(const Tag& tag, std::string_view key, int64_t* out) {
  const std::string* v = tag.find(key);
  return v && parse_int(*v, *out) && *out >= 0;
}

Result<RawMesh> VtuScanner::parse(bool* points_at_rest, std::vector<double>* displacement,
                                  VtuFile* arrays) {
  std::vector<std::string_view> stack;  // open elements
  std::optional<Array> points, connectivity, offsets, types, region;
  std::vector<Region> regions;
  int64_t point_count = -1, cell_count = -1;
  bool seen_file = false;
  *points_at_rest = false;
  while (true) {
    Result<std::optional<Tag>> next = next_tag();
    if (!next) return next.error();
    if (!next->has_value()) break;
    const Tag& tag = **next;
    if (tag.closing) {
      if (stack.empty() || stack.back() != tag.name)
        return fail(tag.offset, "unexpected </%s>", excerpt(tag.name).c_str());
      stack.pop_back();
      continue;
    }
    if (tag.name == "VTKFile") {
      const std::string* type = tag.find("type");
      if (!type || *type != "UnstructuredGrid")
        return fail(tag.offset, "VTK file type '%s' is not supported (UnstructuredGrid only)",
                    type ? excerpt(*type).c_str() : "");
      if (const std::string* c = tag.find("compressor"))
        return fail(tag.offset, "compressed data (%s) is not supported", excerpt(*c).c_str());
      if (const std::string* b = tag.find("byte_order"); b && *b != "LittleEndian")
        return fail(tag.offset, "byte order '%s' is not supported (LittleEndian only)",
                    excerpt(*b).c_str());
      const std::string* h = tag.find("header_type");
      if (h && *h != "UInt64" && *h != "UInt32")
        return fail(tag.offset, "header_type '%s' is not supported", excerpt(*h).c_str());
      header_uint64_ = h && *h == "UInt64";
      seen_file = true;
    } else if (!seen_file) {
      return fail(tag.offset, "not a VTK XML file (no <VTKFile> before <%s>)",
                  excerpt(tag.name).c_str());
    } else if (tag.name == "AppendedData") {
      return fail(tag.offset, "appended data is not supported (zona reads inline ascii or "
                  "base64 arrays, as it writes them)");
    } else if (tag.name == "Piece") {
      if (point_count >= 0)
        return fail(tag.offset, "more than one <Piece> is not supported");
      if (!count_attribute(tag, "NumberOfPoints", &point_count) ||
          !count_attribute(tag, "NumberOfCells", &cell_count))
        return fail(tag.offset, "<Piece> needs NumberOfPoints and NumberOfCells");
    } else if (tag.name == "DataArray") {
      Result<Array> array = read_array(tag);
      if (!array) return array.error();
      const std::string_view parent = stack.empty() ? std::string_view{} : stack.back();
      Array& a = *array;
      // Every data array for read_vtu, copied before the mesh's own arrays take theirs.
      if (arrays) {
        std::vector<VtkField>* into = parent == "PointData"   ? &arrays->point_data
                                      : parent == "CellData"  ? &arrays->cell_data
                                      : parent == "FieldData" ? &arrays->field_data
                                                              : nullptr;
        if (into) into->push_back(VtkField{a.name, a.components, a.values});
      }
      if (parent == "Points") {
        if (a.components != 3)
          return fail(tag.offset, "points have %d components; expected 3", a.components);
        points = std::move(a);
      } else if (parent == "Cells") {
        if (a.name == "connectivity") connectivity = std::move(a);
        else if (a.name == "offsets") offsets = std::move(a);
        else if (a.name == "types") types = std::move(a);
      } else if (parent == "CellData") {
        if (a.name == "region") region = std::move(a);
      } else if (parent == "PointData") {
        if (a.name == "displacement" && a.components == 3) displacement->swap(a.values);
      } else if (parent == "FieldData") {
        if (a.name == "points_at_rest" && a.values.size() == 1) *points_at_rest = a.values[0] == 1;
        if (a.name.rfind("region:", 0) == 0 && a.values.size() == 1 && a.name.size() > 7)
          regions.push_back({static_cast<int32_t>(a.values[0]), a.name.substr(7)});
      }
      continue;  // read_array consumed the closing tag
    }
    if (!tag.self_closing) stack.push_back(tag.name);
  }
  if (!seen_file) return fail(0, "not a VTK XML file (no <VTKFile>)");
  if (point_count < 0) return fail(pos_, "no <Piece> in the file");
  if (!points) return fail(pos_, "no <Points> array");
  if (!connectivity || !offsets || !types)
    return fail(pos_, "<Cells> needs connectivity, offsets and types arrays");
  const size_t np = static_cast<size_t>(point_count), nc = static_cast<size_t>(cell_count);
  if (points->values.size() != 3 * np)
    return fail(pos_, "%zu point coordinates for NumberOfPoints %zu", points->values.size(), np);
  if (types->values.size() != nc || offsets->values.size() != nc)
    return fail(pos_, "%zu types and %zu offsets for NumberOfCells %zu", types->values.size(),
                offsets->values.size(), nc);
  if (connectivity->values.size() != 4 * nc)
    return fail(pos_, "%zu connectivity entries for %zu cells; expected 4 per tetrahedron",
                connectivity->values.size(), nc);
  if (region && region->values.size() != nc)
    return fail(pos_, "cell array 'region' has %zu values for %zu cells", region->values.size(), nc);
  if (!displacement->empty() && displacement->size() != 3 * np)
    return fail(pos_, "point array 'displacement' has %zu values for %zu points",
                displacement->size(), np);
  // read_vtu's arrays hold one tuple per point or per cell.
  if (arrays) {
    for (const auto& [fields, count, kind] :
         {std::tuple{&arrays->point_data, np, "point"}, std::tuple{&arrays->cell_data, nc, "cell"}})
      for (const VtkField& f : *fields)
        if (f.values.size() != count * static_cast<size_t>(f.components))
          return fail(pos_, "%s array '%s' has %zu values for %zu %ss of %d component(s)", kind,
                      excerpt(f.name).c_str(), f.values.size(), count, kind, f.components);
  }
  RawMesh raw;
  raw.points.resize(np);
  for (size_t i = 0; i < np; ++i)
    raw.points[i] = Vec3d{points->values[3 * i], points->values[3 * i + 1], points->values[3 * i + 2]};
  raw.tets.resize(nc);
  raw.tet_region.assign(nc, 0);
  for (size_t c = 0; c < nc; ++c) {
    if (types->values[c] != kVtkTetra)
      return fail(pos_, "cell %zu has VTK type %g; only linear tetrahedra (10) are supported", c,
                  types->values[c]);
    if (offsets->values[c] != static_cast<double>(4 * (c + 1)))
      return fail(pos_, "cell %zu: offset %g; expected %zu (4 corners per tetrahedron)", c,
                  offsets->values[c], 4 * (c + 1));
    for (int k = 0; k < 4; ++k) {
      const double v = connectivity->values[4 * c + static_cast<size_t>(k)];
      if (!(v >= 0 && v < static_cast<double>(np)) || v != static_cast<double>(static_cast<int64_t>(v)))
        return fail(pos_, "cell %zu references point %g, out of range [0, %zu)", c, v, np);
      raw.tets[c][k] = static_cast<int32_t>(v);
    }
    if (region) {
      const double r = region->values[c];
      if (!(r >= 0 && r <= 2147483647.0))
        return fail(pos_, "cell %zu: region %g is not a tag in [0, 2^31)", c, r);
      raw.tet_region[c] = static_cast<int32_t>(r);
    }
  }
  raw.regions = std::move(regions);
  return raw;
}

}  // namespace

Result<RawMesh> parse_vtu(std::string_view data, const std::string& name, bool deformed) {
  VtuScanner scanner(data, name);
  bool at_rest = false;
  std::vector<double> displacement;
  Result<RawMesh> raw = scanner.parse(&at_rest, &displacement);
  if (!raw) return raw;
  // A zona frame: its points are at rest and the deformed configuration adds the displacement.
  if (deformed && at_rest && !displacement.empty())
    for (size_t i = 0; i < raw->points.size(); ++i)
      raw->points[i] += Vec3d{displacement[3 * i], displacement[3 * i + 1], displacement[3 * i + 2]};
  return raw;
}

Result<VtuFile> parse_vtu_file(std::string_view data, const std::string& name) {
  VtuScanner scanner(data, name);
  bool at_rest = false;
  std::vector<double> displacement;
  VtuFile file;
  Result<RawMesh> raw = scanner.parse(&at_rest, &displacement, &file);
  if (!raw) return raw.error();
  file.points = std::move(raw->points);
  file.tets = std::move(raw->tets);
  file.regions = std::move(raw->regions);
  return file;
}

}  // namespace zona::io_detail

namespace zona {

Result<VtuFile> read_vtu(const std::string& path) {
  Result<std::string> data = io_detail::read_file(path);
  if (!data) return data.error();
  return io_detail::parse_vtu_file(*data, path);
}

}  // namespace zona
