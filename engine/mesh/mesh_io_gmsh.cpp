// Gmsh .msh reader: MSH 2.x and 4.1, ASCII and binary (either byte order), linear tetrahedra
// with physical tags as regions.
//
// Layout references: the "MSH file format" chapter of the Gmsh manual (versions 2.2 and 4.1).
// Every count is checked against the bytes left before it drives a loop or a reservation.
#include <climits>
#include <cstring>
#include <map>
#include <set>

#include "engine/mesh/mesh_io_internal.h"

namespace zona::io_detail {
namespace {

constexpr int kGmshTet = 4;  // element type of the 4-node tetrahedron

// Nodes per element of the Gmsh element types, needed to step over the elements we do not
// keep in binary files (ASCII files are skipped line by line). -1: unknown type.
int gmsh_element_nodes(int64_t type) {
  switch (type) {
    case 1: return 2;    // line
    case 2: return 3;    // triangle
    case 3: return 4;    // quadrangle
    case 4: return 4;    // tetrahedron
    case 5: return 8;    // hexahedron
    case 6: return 6;    // prism
    case 7: return 5;    // pyramid
    case 8: return 3;    // 3-node line
    case 9: return 6;    // 6-node triangle
    case 10: return 9;   // 9-node quadrangle
    case 11: return 10;  // 10-node tetrahedron
    case 12: return 27;  // 27-node hexahedron
    case 13: return 18;  // 18-node prism
    case 14: return 14;  // 14-node pyramid
    case 15: return 1;   // point
    case 16: return 8;   // 8-node quadrangle
    case 17: return 20;  // 20-node hexahedron
    case 18: return 15;  // 15-node prism
    case 19: return 13;  // 13-node pyramid
    case 20: return 9;   // 9-node incomplete triangle
    case 21: return 10;  // 10-node triangle
    case 22: return 12;  // 12-node incomplete triangle
    case 23: return 15;  // 15-node triangle
    case 24: return 15;  // 15-node incomplete triangle
    case 25: return 21;  // 21-node triangle
    case 26: return 4;   // 4-node edge
    case 27: return 5;   // 5-node edge
    case 28: return 6;   // 6-node edge
    case 29: return 20;  // 20-node tetrahedron
    case 30: return 35;  // 35-node tetrahedron
    case 31: return 56;  // 56-node tetrahedron
    case 92: return 64;  // 64-node hexahedron
    case 93: return 125; // 125-node hexahedron
    default: return -1;
  }
}

class GmshReader {
 public:
  GmshReader(std::string_view data, const std::string& name) : c_(data, name), name_(name) {}

  Result<RawMesh> run() {
    std::string_view t;
    if (!c_.token(t, "$MeshFormat")) return c_.error();
    if (t != "$MeshFormat") {
      c_.fail("not a Gmsh file: expected $MeshFormat, got '%s'", excerpt(t).c_str());
      return c_.error();
    }
    if (!format()) return c_.error();
    while (true) {
      c_.skip_space();
      if (c_.at_end()) break;
      if (!c_.token(t, "a section")) break;
      if (t.size() < 2 || t[0] != '$') {
        c_.fail("expected a section such as $Nodes, got '%s'", excerpt(t).c_str());
        break;
      }
      const std::string section(t.substr(1));
      bool ok;
      if (section.rfind("End", 0) == 0)
        ok = c_.fail("$%s without its opening section", excerpt(section).c_str());
      else if (section == "MeshFormat")
        ok = c_.fail("second $MeshFormat section");
      else if (section == "PhysicalNames")
        ok = physical_names();
      else if (section == "Entities" && major_ == 4)
        ok = entities();
      else if (section == "Nodes")
        ok = major_ == 4 ? nodes4() : nodes2();
      else if (section == "Elements")
        ok = major_ == 4 ? elements4() : elements2();
      else
        ok = skip_section(section);  // $NodeData, $Periodic, $Comments, ...
      if (!ok) break;
    }
    if (!c_.failed() && !have_nodes_) c_.fail("no $Nodes section in the file");
    if (c_.failed()) return c_.error();
    return std::move(out_);
  }

 private:
  // ---- sections ----

  bool format() {
    std::string_view version;
    if (!c_.token(version, "MSH version")) return false;
    if (version == "4.1") {
      major_ = 4;
    } else if (version == "2" || version == "2.0" || version == "2.1" || version == "2.2") {
      major_ = 2;
    } else {
      return c_.fail("unsupported MSH version '%s' (2.2 and 4.1 are read; re-save with gmsh "
                     "-format msh41)", excerpt(version).c_str());
    }
    int64_t file_type = 0, data_size = 0;
    if (!c_.integer(file_type, "file type (0 ASCII, 1 binary)", 0, 1)) return false;
    if (!c_.integer(data_size, "data size", 1, 64)) return false;
    binary_ = file_type == 1;
    if (binary_) {
      // MSH 2 binary stores doubles of data-size bytes (always 8); MSH 4.1's data size is the
      // width of its size_t fields.
      if (major_ == 2 && data_size != 8)
        return c_.fail("data size %lld unsupported in binary MSH 2 (must be 8)",
                       static_cast<long long>(data_size));
      if (major_ == 4 && data_size != 4 && data_size != 8)
        return c_.fail("data size %lld unsupported in binary MSH 4.1 (must be 4 or 8)",
                       static_cast<long long>(data_size));
      size_bytes_ = static_cast<size_t>(data_size);
      if (!c_.end_of_line()) return false;
      c_.use_byte_offsets();
      // The integer 1 written in the writer's byte order tells us whether to swap.
      int32_t one = 0;
      if (!c_.i32(one, "endianness marker")) return false;
      if (one != 1) {
        if (static_cast<int32_t>(__builtin_bswap32(static_cast<uint32_t>(one))) != 1)
          return c_.fail("bad endianness marker %d (expected the integer 1)", one);
        c_.set_swap(true);
      }
    }
    return end_section("MeshFormat");
  }

  bool physical_names() {
    int64_t n = 0;
    if (!c_.integer(n, "physical name count", 0, INT32_MAX)) return false;
    if (!c_.check_count(static_cast<uint64_t>(n), 6, "physical name count")) return false;
    for (int64_t i = 0; i < n; ++i) {
      int64_t dim = 0, tag = 0;
      if (!c_.integer(dim, "physical dimension", 0, 3)) return false;
      if (!c_.integer(tag, "physical tag", 1, INT32_MAX)) return false;
      std::string_view line = c_.rest_of_line();
      const size_t open = line.find('"');
      const size_t close = line.rfind('"');
      if (open == std::string_view::npos || close == open)
        return c_.fail("physical name must be in double quotes, got '%s'",
                       excerpt(line).c_str());
      if (dim != 3) continue;  // only volumes carry tetrahedra
      // The first name of a tag wins; a set keeps this linear however many names there are.
      const auto tag32 = static_cast<int32_t>(tag);
      if (named_.insert(tag32).second)
        out_.regions.push_back({tag32, std::string(line.substr(open + 1, close - open - 1))});
    }
    return end_section("PhysicalNames");
  }

  bool entities() {
    if (binary_ && !c_.end_of_line()) return false;
    uint64_t count[4];
    for (uint64_t& n : count)
      if (!size_field(n, "entity count")) return false;
    const uint64_t min_bytes = binary_ ? 4 + 24 + size_bytes_ : 10;
    for (uint64_t n : count)
      if (!c_.check_count(n, min_bytes, "entity count")) return false;
    for (int dim = 0; dim < 4; ++dim) {
      for (uint64_t i = 0; i < count[dim]; ++i) {
        int32_t tag = 0;
        if (!int_field(tag, "entity tag", INT32_MIN, INT32_MAX)) return false;
        // A point's coordinates or a bounding box: not needed here.
        if (!skip_reals(dim == 0 ? 3 : 6, "entity bounding box")) return false;
        uint64_t nphys = 0;
        if (!size_field(nphys, "physical tag count")) return false;
        if (!c_.check_count(nphys, binary_ ? 4 : 2, "physical tag count")) return false;
        for (uint64_t k = 0; k < nphys; ++k) {
          int32_t phys = 0;
          if (!int_field(phys, "physical tag", INT32_MIN, INT32_MAX)) return false;
          if (k == 0) entity_physical_.emplace(std::make_pair(dim, tag), phys);
        }
        if (nphys > 1 && dim == 3)
          out_.warnings.push_back(name_ + ": volume entity " + std::to_string(tag) + " has " +
                                  std::to_string(nphys) +
                                  " physical tags; its tetrahedra get the first");
        if (dim == 0) continue;
        uint64_t nbound = 0;
        if (!size_field(nbound, "bounding entity count")) return false;
        if (!c_.check_count(nbound, binary_ ? 4 : 2, "bounding entity count")) return false;
        for (uint64_t k = 0; k < nbound; ++k) {
          int32_t b = 0;
          if (!int_field(b, "bounding entity tag", INT32_MIN, INT32_MAX)) return false;
        }
      }
    }
    return end_section("Entities");
  }

  bool nodes2() {
    if (have_nodes_) return c_.fail("second $Nodes section");
    have_nodes_ = true;
    int64_t n = 0;
    if (!c_.integer(n, "node count", 0, INT32_MAX)) return false;
    if (!c_.check_count(static_cast<uint64_t>(n), binary_ ? 28 : 8, "node count")) return false;
    out_.points.reserve(static_cast<size_t>(n));
    if (binary_ && !c_.end_of_line()) return false;
    for (int64_t i = 0; i < n; ++i) {
      int64_t tag = 0;
      if (binary_) {
        int32_t t32 = 0;
        if (!c_.i32(t32, "node tag")) return false;
        if (t32 < 0) return c_.fail("node tag %d is negative", t32);
        tag = t32;
      } else if (!c_.integer(tag, "node tag", 0, INT64_MAX)) {
        return false;
      }
      if (!tags_.add(static_cast<uint64_t>(tag)))
        return c_.fail("node tag %lld appears twice", static_cast<long long>(tag));
      Vec3d p;
      if (!real_field(p.x, "node x") || !real_field(p.y, "node y") ||
          !real_field(p.z, "node z"))
        return false;
      out_.points.push_back(p);
    }
    return end_section("Nodes");
  }

  bool nodes4() {
    if (have_nodes_) return c_.fail("second $Nodes section");
    have_nodes_ = true;
    if (binary_ && !c_.end_of_line()) return false;
    uint64_t nblocks = 0, nnodes = 0, min_tag = 0, max_tag = 0;
    if (!size_field(nblocks, "node block count") || !size_field(nnodes, "node count") ||
        !size_field(min_tag, "minimum node tag") || !size_field(max_tag, "maximum node tag"))
      return false;
    if (nnodes > INT32_MAX) return c_.fail("%llu nodes exceed the int32 index range", ull(nnodes));
    if (!c_.check_count(nblocks, binary_ ? 12 + size_bytes_ : 8, "node block count") ||
        !c_.check_count(nnodes, binary_ ? 24 + size_bytes_ : 8, "node count"))
      return false;
    out_.points.reserve(static_cast<size_t>(nnodes));
    uint64_t total = 0;
    for (uint64_t b = 0; b < nblocks; ++b) {
      int32_t dim = 0, entity = 0, parametric = 0;
      uint64_t n = 0;
      if (!int_field(dim, "entity dimension", 0, 3) ||
          !int_field(entity, "entity tag", INT32_MIN, INT32_MAX) ||
          !int_field(parametric, "parametric flag", 0, 1) || !size_field(n, "block node count"))
        return false;
      if (n > nnodes - total)
        return c_.fail("node blocks hold more than the %llu nodes declared", ull(nnodes));
      const int nparam = parametric ? dim : 0;  // u (curves), u v (surfaces), u v w (volumes)
      if (!c_.check_count(n, binary_ ? size_bytes_ + 24 + 8 * nparam : 8, "block node count"))
        return false;
      for (uint64_t k = 0; k < n; ++k) {
        uint64_t tag = 0;
        if (!size_field(tag, "node tag")) return false;
        if (!tags_.add(tag)) return c_.fail("node tag %llu appears twice", ull(tag));
      }
      for (uint64_t k = 0; k < n; ++k) {
        Vec3d p;
        if (!real_field(p.x, "node x") || !real_field(p.y, "node y") ||
            !real_field(p.z, "node z") || !skip_reals(nparam, "parametric coordinate"))
          return false;
        out_.points.push_back(p);
      }
      total += n;
    }
    if (total != nnodes)
      return c_.fail("node blocks hold %llu nodes; the header declares %llu", ull(total),
                     ull(nnodes));
    return end_section("Nodes");
  }

  bool elements2() {
    if (!have_nodes_) return c_.fail("$Elements before $Nodes");
    if (have_elements_) return c_.fail("second $Elements section");
    have_elements_ = true;
    int64_t n = 0;
    if (!c_.integer(n, "element count", 0, INT64_MAX)) return false;
    if (!c_.check_count(static_cast<uint64_t>(n), 8, "element count")) return false;
    if (binary_) {
      if (!c_.end_of_line()) return false;
      int64_t done = 0;
      while (done < n) {
        // Block header: type, number of elements that follow, number of tags.
        int32_t type = 0, follow = 0, ntags = 0;
        if (!c_.i32(type, "element type") || !c_.i32(follow, "element block size") ||
            !c_.i32(ntags, "element tag count"))
          return false;
        if (follow < 1 || follow > n - done)
          return c_.fail("element block of %d elements, %lld left of the declared count",
                         follow, static_cast<long long>(n - done));
        if (ntags < 0 || ntags > 1024) return c_.fail("element tag count %d out of range", ntags);
        const int nn = gmsh_element_nodes(type);
        if (nn < 0) return c_.fail("unsupported element type %d", type);
        const uint64_t bytes = 4 * static_cast<uint64_t>(1 + ntags + nn);
        if (!c_.check_count(static_cast<uint64_t>(follow), bytes, "element block size"))
          return false;
        if (type != kGmshTet) {
          if (!c_.skip_bytes(static_cast<uint64_t>(follow), bytes, "elements")) return false;
        } else {
          for (int32_t e = 0; e < follow; ++e) {
            int32_t id = 0, region = 0, tag = 0;
            if (!c_.i32(id, "element tag")) return false;
            for (int32_t k = 0; k < ntags; ++k) {
              if (!c_.i32(tag, "element tag")) return false;
              if (k == 0) region = tag;
            }
            uint64_t nodes[4];
            for (uint64_t& v : nodes) {
              int32_t t32 = 0;
              if (!c_.i32(t32, "element node")) return false;
              v = t32 < 0 ? UINT64_MAX : static_cast<uint64_t>(t32);
            }
            if (!add_tet(id, nodes, region)) return false;
          }
        }
        done += follow;
      }
      return end_section("Elements");
    }
    for (int64_t i = 0; i < n; ++i) {
      int64_t id = 0, type = 0, ntags = 0, tag = 0;
      int32_t region = 0;
      if (!c_.integer(id, "element tag", INT64_MIN, INT64_MAX) ||
          !c_.integer(type, "element type", INT32_MIN, INT32_MAX) ||
          !c_.integer(ntags, "element tag count", 0, 1024))
        return false;
      for (int64_t k = 0; k < ntags; ++k) {
        if (!c_.integer(tag, "element tag", k == 0 ? INT32_MIN : INT64_MIN,
                        k == 0 ? INT32_MAX : INT64_MAX))
          return false;
        if (k == 0) region = static_cast<int32_t>(tag);  // physical tag
      }
      if (type != kGmshTet) {
        c_.skip_line();
        continue;
      }
      uint64_t nodes[4];
      for (uint64_t& v : nodes) {
        int64_t t = 0;
        if (!c_.integer(t, "element node", 0, INT64_MAX)) return false;
        v = static_cast<uint64_t>(t);
      }
      if (!rest_of_line_blank() || !add_tet(id, nodes, region)) return false;
    }
    return end_section("Elements");
  }

  bool elements4() {
    if (!have_nodes_) return c_.fail("$Elements before $Nodes");
    if (have_elements_) return c_.fail("second $Elements section");
    have_elements_ = true;
    if (binary_ && !c_.end_of_line()) return false;
    uint64_t nblocks = 0, nelements = 0, min_tag = 0, max_tag = 0;
    if (!size_field(nblocks, "element block count") ||
        !size_field(nelements, "element count") || !size_field(min_tag, "minimum element tag") ||
        !size_field(max_tag, "maximum element tag"))
      return false;
    if (!c_.check_count(nblocks, binary_ ? 12 + size_bytes_ : 8, "element block count") ||
        !c_.check_count(nelements, binary_ ? 2 * size_bytes_ : 4, "element count"))
      return false;
    uint64_t total = 0;
    for (uint64_t b = 0; b < nblocks; ++b) {
      int32_t dim = 0, entity = 0, type = 0;
      uint64_t n = 0;
      if (!int_field(dim, "entity dimension", 0, 3) ||
          !int_field(entity, "entity tag", INT32_MIN, INT32_MAX) ||
          !int_field(type, "element type", INT32_MIN, INT32_MAX) ||
          !size_field(n, "block element count"))
        return false;
      if (n > nelements - total)
        return c_.fail("element blocks hold more than the %llu elements declared",
                       ull(nelements));
      const int nn = gmsh_element_nodes(type);
      if (binary_ && nn < 0) return c_.fail("unsupported element type %d", type);
      const uint64_t fields = 1 + static_cast<uint64_t>(nn < 0 ? 1 : nn);
      if (!c_.check_count(n, binary_ ? fields * size_bytes_ : 2 * fields, "block element count"))
        return false;
      total += n;
      if (type != kGmshTet) {
        if (binary_) {
          if (!c_.skip_bytes(n, fields * size_bytes_, "elements")) return false;
        } else {
          for (uint64_t e = 0; e < n && !c_.at_end(); ++e) {  // one element per line
            c_.skip_space();
            c_.skip_line();
          }
        }
        continue;
      }
      const auto it = entity_physical_.find(std::make_pair(dim, entity));
      const int32_t region = it == entity_physical_.end() ? 0 : it->second;
      for (uint64_t e = 0; e < n; ++e) {
        uint64_t id = 0, nodes[4];
        if (!size_field(id, "element tag")) return false;
        for (uint64_t& v : nodes)
          if (!size_field(v, "element node")) return false;
        if (!binary_ && !rest_of_line_blank()) return false;
        if (!add_tet(static_cast<int64_t>(id), nodes, region)) return false;
      }
    }
    if (total != nelements)
      return c_.fail("element blocks hold %llu elements; the header declares %llu", ull(total),
                     ull(nelements));
    return end_section("Elements");
  }

  // ---- helpers ----

  static unsigned long long ull(uint64_t v) { return static_cast<unsigned long long>(v); }

  bool end_section(const char* section) {
    return c_.keyword(std::string("$End") + section);
  }

  // Steps over a section we do not read, to its "$End<name>" token.
  bool skip_section(const std::string& section) {
    const std::string end = "$End" + section;
    const std::string_view data = c_.data();
    size_t at = c_.offset();
    while ((at = data.find(end, at)) != std::string_view::npos) {
      const size_t after = at + end.size();
      const bool starts = at == 0 || data[at - 1] == '\n' || data[at - 1] == ' ' ||
                          data[at - 1] == '\r' || data[at - 1] == '\t';
      const bool ends = after == data.size() || data[after] == '\n' || data[after] == '\r' ||
                        data[after] == ' ' || data[after] == '\t';
      if (starts && ends) {
        c_.jump_to(after);
        return true;
      }
      at = after;
    }
    return c_.fail("section $%s has no %s", excerpt(section).c_str(), excerpt(end).c_str());
  }

  bool rest_of_line_blank() {
    const std::string_view rest = c_.rest_of_line();
    for (char ch : rest)
      if (ch != ' ' && ch != '\t' && ch != '\r')
        return c_.fail("extra fields after a tetrahedron's four nodes: '%s'",
                       excerpt(rest).c_str());
    return true;
  }

  // MSH 4.1 size_t field: an ASCII integer or data-size binary bytes.
  bool size_field(uint64_t& value, const char* what) {
    if (binary_) return c_.unsigned_field(value, size_bytes_, what);
    int64_t v = 0;
    if (!c_.integer(v, what, 0, INT64_MAX)) return false;
    value = static_cast<uint64_t>(v);
    return true;
  }

  // MSH 4.1 int field: an ASCII integer or 4 binary bytes, in [lo, hi].
  bool int_field(int32_t& value, const char* what, int64_t lo, int64_t hi) {
    int64_t v = 0;
    if (binary_) {
      if (!c_.i32(value, what)) return false;
      v = value;
      if (v < lo || v > hi)
        return c_.fail("%s %lld out of range [%lld, %lld]", what, static_cast<long long>(v),
                       static_cast<long long>(lo), static_cast<long long>(hi));
      return true;
    }
    if (!c_.integer(v, what, lo, hi)) return false;
    value = static_cast<int32_t>(v);
    return true;
  }

  bool real_field(double& value, const char* what) {
    return binary_ ? c_.f64(value, what) : c_.real(value, what);
  }

  // Reals we do not keep (bounding boxes, parametric coordinates): syntax-checked in ASCII.
  bool skip_reals(int count, const char* what) {
    if (binary_) return c_.skip_bytes(static_cast<uint64_t>(count), 8, what);
    for (int k = 0; k < count; ++k) {
      std::string_view t;
      double v = 0;
      if (!c_.token(t, what)) return false;
      if (!parse_real(t, v)) return c_.fail("expected %s, got '%s'", what, excerpt(t).c_str());
    }
    return true;
  }

  bool add_tet(int64_t id, const uint64_t (&nodes)[4], int32_t region) {
    Tet tet;
    for (int k = 0; k < 4; ++k) {
      const int64_t index = tags_.find(nodes[k]);
      if (index < 0)
        return c_.fail("element %lld uses node %llu, which $Nodes does not define",
                       static_cast<long long>(id), ull(nodes[k]));
      tet[k] = static_cast<int32_t>(index);  // < point count <= INT32_MAX
    }
    if (out_.tets.size() >= static_cast<size_t>(INT32_MAX))
      return c_.fail("more tetrahedra than the int32 index range");
    out_.tets.push_back(tet);
    out_.tet_region.push_back(region);
    return true;
  }

  Cursor c_;
  std::string name_;
  int major_ = 0;
  bool binary_ = false;
  uint64_t size_bytes_ = 8;
  bool have_nodes_ = false;
  bool have_elements_ = false;
  NodeTagMap tags_;
  std::map<std::pair<int, int32_t>, int32_t> entity_physical_;  // (dim, entity) -> physical
  std::set<int32_t> named_;                                     // tags with a name already
  RawMesh out_;
};

}  // namespace

Result<RawMesh> parse_gmsh(std::string_view data, const std::string& name) {
  GmshReader reader(data, name);
  return reader.run();
}

}  // namespace zona::io_detail
