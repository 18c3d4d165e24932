// TetGen .node/.ele reader: points, tetrahedra (4 or 10 nodes), attributes, boundary markers,
// '#' comments, 0- or 1-based numbering; the first tetrahedron attribute is the region.
//
// Layout reference: the TetGen manual's file formats chapter. The first point's index sets the
// numbering base (0 or 1) for both files, as TetGen does.
#include <climits>
#include <cmath>

#include "engine/mesh/mesh_io_internal.h"

namespace zona::io_detail {
namespace {

// Attribute counts above this are surely corrupt headers (TetGen writes a handful).
constexpr int64_t kMaxAttributes = 1 << 16;

struct NodeFile {
  std::vector<Vec3d> points;
  int64_t base = 0;  // index of the first point: 0 or 1
};

bool too_many_fields(Cursor& c, size_t found, size_t allowed, const char* what) {
  return c.fail("%s has %zu fields; expected at most %zu", what, found, allowed);
}

bool parse_node(Cursor& c, NodeFile& out) {
  std::vector<std::string_view> f;
  if (!c.record(f)) {
    if (!c.failed()) c.fail("empty .node file: expected the header 'points dimension "
                            "attributes markers'");
    return false;
  }
  if (f.size() > 4) return too_many_fields(c, f.size(), 4, ".node header");
  // Missing trailing header fields default as in TetGen: 3 dimensions, no attributes/markers.
  int64_t n = 0, dim = 3, nattr = 0, markers = 0;
  if (!c.integer_field(f[0], n, "point count", 1, INT32_MAX)) return false;
  if (f.size() > 1 && !c.integer_field(f[1], dim, "dimension", 3, 3)) return false;
  if (f.size() > 2 && !c.integer_field(f[2], nattr, "point attribute count", 0, kMaxAttributes))
    return false;
  if (f.size() > 3 && !c.integer_field(f[3], markers, "boundary marker count", 0, 1))
    return false;
  const auto fields = static_cast<size_t>(4 + nattr + markers);
  if (!c.check_count(static_cast<uint64_t>(n), 2 * fields, "point count")) return false;
  out.points.reserve(static_cast<size_t>(n));
  for (int64_t i = 0; i < n; ++i) {
    if (!c.record(f)) {
      if (!c.failed())
        c.fail("unexpected end of file: %lld of the %lld points declared",
               static_cast<long long>(i), static_cast<long long>(n));
      return false;
    }
    if (f.size() != fields)
      return c.fail("point line has %zu fields; expected %zu (index, x, y, z, %lld attributes, "
                    "%lld boundary markers)", f.size(), fields, static_cast<long long>(nattr),
                    static_cast<long long>(markers));
    int64_t index = 0;
    if (i == 0) {
      if (!c.integer_field(f[0], index, "first point index", 0, 1)) return false;
      out.base = index;
    } else {
      if (!c.integer_field(f[0], index, "point index", INT64_MIN, INT64_MAX)) return false;
      if (index != out.base + i)
        return c.fail("point index %lld out of sequence; expected %lld",
                      static_cast<long long>(index), static_cast<long long>(out.base + i));
    }
    Vec3d p;
    if (!c.real_field(f[1], p.x, "point x") || !c.real_field(f[2], p.y, "point y") ||
        !c.real_field(f[3], p.z, "point z"))
      return false;
    for (size_t k = 4; k < 4 + static_cast<size_t>(nattr); ++k) {
      double a = 0;
      if (!parse_real(f[k], a))
        return c.fail("expected point attribute, got '%s'", excerpt(f[k]).c_str());
    }
    if (markers) {
      int64_t m = 0;
      if (!c.integer_field(f[fields - 1], m, "boundary marker", INT64_MIN, INT64_MAX))
        return false;
    }
    out.points.push_back(p);
  }
  if (c.record(f))
    return c.fail("more point lines than the %lld declared", static_cast<long long>(n));
  return !c.failed();
}

bool parse_ele(Cursor& c, int64_t base, int64_t np, RawMesh& out) {
  std::vector<std::string_view> f;
  if (!c.record(f)) {
    if (!c.failed()) c.fail("empty .ele file: expected the header 'tetrahedra nodes attributes'");
    return false;
  }
  if (f.size() > 3) return too_many_fields(c, f.size(), 3, ".ele header");
  int64_t n = 0, per = 4, nattr = 0;
  if (!c.integer_field(f[0], n, "tetrahedron count", 1, INT32_MAX)) return false;
  if (f.size() > 1 && !c.integer_field(f[1], per, "nodes per tetrahedron", 4, 10)) return false;
  if (per != 4 && per != 10)
    return c.fail("nodes per tetrahedron must be 4 or 10, got %lld", static_cast<long long>(per));
  if (f.size() > 2 &&
      !c.integer_field(f[2], nattr, "tetrahedron attribute count", 0, kMaxAttributes))
    return false;
  const auto fields = static_cast<size_t>(1 + per + nattr);
  if (!c.check_count(static_cast<uint64_t>(n), 2 * fields, "tetrahedron count")) return false;
  out.tets.reserve(static_cast<size_t>(n));
  out.tet_region.reserve(static_cast<size_t>(n));
  for (int64_t i = 0; i < n; ++i) {
    if (!c.record(f)) {
      if (!c.failed())
        c.fail("unexpected end of file: %lld of the %lld tetrahedra declared",
               static_cast<long long>(i), static_cast<long long>(n));
      return false;
    }
    if (f.size() != fields)
      return c.fail("tetrahedron line has %zu fields; expected %zu (index, %lld nodes, %lld "
                    "attributes)", f.size(), fields, static_cast<long long>(per),
                    static_cast<long long>(nattr));
    int64_t index = 0;
    if (!c.integer_field(f[0], index, "tetrahedron index", INT64_MIN, INT64_MAX)) return false;
    Tet tet;
    // Corners come first in 10-node elements; the mid-edge nodes are checked, then dropped.
    for (size_t k = 1; k <= static_cast<size_t>(per); ++k) {
      int64_t v = 0;
      if (!c.integer_field(f[k], v, "node index", base, base + np - 1)) return false;
      if (k <= 4) tet[k - 1] = static_cast<int32_t>(v - base);
    }
    int32_t region = 0;
    for (size_t k = 1 + static_cast<size_t>(per); k < fields; ++k) {
      double a = 0;
      if (!parse_real(f[k], a) || !std::isfinite(a))
        return c.fail("expected tetrahedron attribute, got '%s'", excerpt(f[k]).c_str());
      if (k == 1 + static_cast<size_t>(per)) {
        // The region attribute of `tetgen -A`: an integer written as a real.
        if (a != std::floor(a) || a < INT32_MIN || a > INT32_MAX)
          return c.fail("region attribute '%s' is not a 32-bit integer", excerpt(f[k]).c_str());
        region = static_cast<int32_t>(a);
      }
    }
    out.tets.push_back(tet);
    out.tet_region.push_back(region);
  }
  if (c.record(f))
    return c.fail("more tetrahedron lines than the %lld declared", static_cast<long long>(n));
  return !c.failed();
}

}  // namespace

Result<RawMesh> parse_tetgen(std::string_view node, std::string_view ele,
                             const std::string& node_name, const std::string& ele_name) {
  NodeFile nodes;
  {
    Cursor c(node, node_name);
    if (!parse_node(c, nodes)) return c.error();
  }
  RawMesh out;
  out.points = std::move(nodes.points);
  if (ele_name.empty()) return out;  // positions only
  Cursor c(ele, ele_name);
  if (!parse_ele(c, nodes.base, static_cast<int64_t>(out.points.size()), out)) return c.error();
  return out;
}

}  // namespace zona::io_detail
