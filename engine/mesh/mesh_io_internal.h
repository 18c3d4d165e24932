// Shared parts of the mesh readers: a bounds-checked cursor over a file held in memory (text
// tokens with line numbers, binary fields with byte offsets) and the raw mesh they produce.
// Internal to engine/mesh_io*.cpp; not part of the public API.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <unordered_map>
#include <utility>
#include <vector>

#include "engine/core/base.h"
#include "engine/mesh/mesh.h"
#include "engine/mesh/mesh_io.h"
#include "engine/core/vec.h"

namespace zona::io_detail {

/// What a reader found, in file numbering: every point in file order (file units), tetrahedra
/// as indices into `points`, and reader warnings. finish_mesh turns it into a Mesh.
struct RawMesh {
  std::vector<Vec3d> points;        ///< file coordinates, (point_count)
  std::vector<Tet> tets;            ///< indices into points, (tet_count)
  std::vector<int32_t> tet_region;  ///< (tet_count)
  std::vector<Region> regions;      ///< named region tags
  std::vector<std::string> warnings;
};

/// Reads a whole regular file; refuses directories and special files (which could never end).
Result<std::string> read_file(const std::string& path);

/// Drops unreferenced points (keeping file order), scales, runs validate_mesh.
Result<Mesh> finish_mesh(RawMesh raw, const std::string& name, const ReadMeshOptions& options,
                         std::vector<std::string>* warnings);

/// The positions read_mesh would number (or every point when there are no tetrahedra), scaled.
Result<std::vector<Vec3d>> finish_positions(RawMesh raw, const std::string& name,
                                            const ReadMeshOptions& options);

/// Gmsh parser (engine/mesh/mesh_io_gmsh.cpp).
Result<RawMesh> parse_gmsh(std::string_view data, const std::string& name);
/// TetGen parsers (engine/mesh/mesh_io_tetgen.cpp). An empty `ele_name` means positions only.
Result<RawMesh> parse_tetgen(std::string_view node, std::string_view ele,
                             const std::string& node_name, const std::string& ele_name);
/// VTU parser (engine/mesh/mesh_io_vtu_read.cpp). `deformed`: a zona frame (points at rest and
/// a displacement array) gives points + displacement.
Result<RawMesh> parse_vtu(std::string_view data, const std::string& name, bool deformed);
/// The same file with every data array, for read_vtu.
Result<VtuFile> parse_vtu_file(std::string_view data, const std::string& name);

/// Writes `data` to `path` (binary mode), reporting open/write/close failures.
Status write_file(const std::string& path, std::string_view data);
/// Checks what the writers rely on: indices in range, one region tag per tetrahedron (or none).
Status check_mesh_for_write(const Mesh& mesh, const std::string& path);
/// `s` with XML's five special characters escaped and control characters as spaces.
std::string xml_escape(std::string_view s);
/// `text` made fit for an XML comment: one line, no "--".
std::string xml_comment_text(std::string_view text);
/// Appends the shortest text that reads back to exactly `value`.
void append_real(std::string& out, double value);
/// Appends an integer in decimal.
void append_int(std::string& out, int64_t value);
/// Appends the bytes of a trivially copyable value (native byte order).
template <class T>
void append_raw(std::string& out, const T& value) {
  out.append(reinterpret_cast<const char*>(&value), sizeof(T));
}

/// Parses a whole token as an integer (optional sign); false on any other text or overflow.
bool parse_int(std::string_view token, int64_t& value);
/// Parses a whole token as a decimal floating-point number; false on other text or overflow.
/// Infinity and NaN parse (the caller decides; coordinates refuse them).
bool parse_real(std::string_view token, double& value);
/// A short, printable, single-line excerpt of untrusted text for an error message.
std::string excerpt(std::string_view text);

/// A cursor over a file in memory. Every read is bounds-checked; the first failure is kept as
/// an Error "<name>:<line>: <what>" (or "<name>:byte <offset>: <what>" once byte offsets are
/// on, for binary files) and every method returns false from then on.
class Cursor {
 public:
  Cursor(std::string_view data, std::string name) : data_(data), name_(std::move(name)) {}

  size_t offset() const { return pos_; }
  size_t remaining() const { return data_.size() - pos_; }
  bool at_end() const { return pos_ >= data_.size(); }
  bool failed() const { return failed_; }
  std::string_view data() const { return data_; }
  /// Report byte offsets instead of line numbers (binary files).
  void use_byte_offsets() { byte_offsets_ = true; }
  /// Binary fields are byte-swapped (the file's endianness marker said so).
  void set_swap(bool swap) { swap_ = swap; }

  /// Records an error at the start of the last item read; returns false.
#if defined(__GNUC__)
  __attribute__((format(printf, 2, 3)))
#endif
  bool fail(const char* format, ...);
  /// The recorded error (call only after a method returned false).
  Error error() const { return Error{error_}; }

  // ---- text ----
  /// Skips whitespace, newlines included.
  void skip_space();
  /// Moves past the next newline (or to the end).
  void skip_line();
  /// Consumes spaces, tabs and '\r' and then exactly one '\n' (binary data follows it).
  bool end_of_line();
  /// Next whitespace-separated token; fails at the end of the file.
  bool token(std::string_view& out, const char* what);
  /// Next token, which must equal `expected`.
  bool keyword(std::string_view expected);
  /// The rest of the current line without its newline, which is consumed.
  std::string_view rest_of_line();
  /// Next token as an integer in [lo, hi].
  bool integer(int64_t& value, const char* what, int64_t lo, int64_t hi);
  /// Next token as a finite real.
  bool real(double& value, const char* what);
  /// `token` (already read) as an integer in [lo, hi] / a finite real; errors name `what`.
  bool integer_field(std::string_view token, int64_t& value, const char* what, int64_t lo,
                     int64_t hi);
  bool real_field(std::string_view token, double& value, const char* what);
  /// The tokens of the next line that has any, after stripping '#' comments (TetGen style;
  /// ',' separates too). False at the end of the file (not an error).
  bool record(std::vector<std::string_view>& tokens);

  // ---- binary ----
  bool i32(int32_t& value, const char* what);
  /// An unsigned field of `bytes` (4 or 8) bytes.
  bool unsigned_field(uint64_t& value, size_t bytes, const char* what);
  /// A finite IEEE double.
  bool f64(double& value, const char* what);
  /// Skips count x size bytes, refusing (without overflow) what the file does not hold.
  bool skip_bytes(uint64_t count, uint64_t size, const char* what);
  /// Fails unless count items of at least min_bytes each fit in the rest of the file: called
  /// before anything is reserved, so a corrupt count cannot cause a huge allocation.
  bool check_count(uint64_t count, uint64_t min_bytes, const char* what);
  /// Moves to `offset` (>= the current one), counting the newlines skipped.
  void jump_to(size_t offset);

 private:
  void mark() {
    mark_pos_ = pos_;
    mark_line_ = line_;
  }
  bool need(size_t bytes, const char* what);

  std::string_view data_;
  std::string name_;
  size_t pos_ = 0;
  size_t line_ = 1;
  size_t mark_pos_ = 0;
  size_t mark_line_ = 1;
  bool byte_offsets_ = false;
  bool swap_ = false;
  bool failed_ = false;
  std::string error_;
};

/// Gmsh node tag -> point index. Gmsh tags are usually 1..n in order, which needs no table;
/// other numberings fall back to a hash map.
class NodeTagMap {
 public:
  /// Adds the next point's tag (its index is the number of tags added before); false if the
  /// tag was already added.
  bool add(uint64_t tag);
  /// Index of `tag`, or -1.
  int64_t find(uint64_t tag) const;
  size_t size() const { return count_; }

 private:
  bool contiguous_ = true;
  uint64_t first_ = 0;
  size_t count_ = 0;
  std::unordered_map<uint64_t, int64_t> map_;  // used once the tags stop being contiguous
};

}  // namespace zona::io_detail
