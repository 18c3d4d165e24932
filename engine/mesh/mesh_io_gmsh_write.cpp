// Gmsh MSH 4.1 writer (ASCII or binary): one volume entity per region tag, carrying the tag as
// its physical tag, so that the file reads back (here and in Gmsh) with the same regions.
#include <algorithm>
#include <cmath>
#include <cstring>

#include "engine/mesh/mesh_io_internal.h"

namespace zona {
namespace {

using io_detail::append_int;
using io_detail::append_raw;
using io_detail::append_real;

// Writes the MSH 4.1 fields in either encoding: ASCII tokens separated by spaces with explicit
// line ends, or native binary (size_t fields as 8 bytes, as the header's data size says).
class MshOut {
 public:
  explicit MshOut(bool binary) : binary_(binary) {}

  void text(std::string_view s) { out_.append(s); }
  void size(uint64_t v) {
    if (binary_) {
      append_raw(out_, v);
    } else {
      append_int(out_, static_cast<int64_t>(v));
      out_.push_back(' ');
    }
  }
  void i32(int32_t v) {
    if (binary_) {
      append_raw(out_, v);
    } else {
      append_int(out_, v);
      out_.push_back(' ');
    }
  }
  void real(double v) {
    if (binary_) {
      append_raw(out_, v);
    } else {
      append_real(out_, v);
      out_.push_back(' ');
    }
  }
  // End of an ASCII record: replaces the trailing space by a newline. Binary records have none.
  void end_record() {
    if (binary_) return;
    if (!out_.empty() && out_.back() == ' ') out_.pop_back();
    out_.push_back('\n');
  }
  // Binary data is followed by a newline before the closing $End line.
  void end_section(std::string_view end) {
    if (binary_) out_.push_back('\n');
    out_.append(end);
  }
  std::string& str() { return out_; }

 private:
  bool binary_;
  std::string out_;
};

// Names go between double quotes on one line: keep them printable.
std::string quoted_name(const std::string& name) {
  std::string out = "\"";
  for (char ch : name) {
    const auto u = static_cast<unsigned char>(ch);
    out.push_back(ch == '"' ? '\'' : (u < 0x20 ? ' ' : ch));
  }
  return out + "\"";
}

}  // namespace

Status write_gmsh41(const std::string& path, const Mesh& mesh, bool binary) {
  if (Status s = io_detail::check_mesh_for_write(mesh, path); !s) return s;
  const size_t nv = mesh.vertex_count();
  const size_t nt = mesh.tet_count();
  auto region_of = [&](size_t t) { return mesh.tet_region.empty() ? 0 : mesh.tet_region[t]; };

  // One volume entity per distinct tag, in ascending tag order (entity tag = position + 1).
  std::vector<int32_t> tags;
  for (size_t t = 0; t < nt; ++t) tags.push_back(region_of(t));
  std::sort(tags.begin(), tags.end());
  tags.erase(std::unique(tags.begin(), tags.end()), tags.end());
  if (!tags.empty() && tags.front() < 0)
    return make_error("%s: region tag %d cannot be written (Gmsh physical tags are positive)",
                      path.c_str(), tags.front());
  if (tags.empty()) tags.push_back(0);  // nodes still need an entity to live on
  auto entity_of = [&](int32_t tag) {
    return static_cast<int32_t>(std::lower_bound(tags.begin(), tags.end(), tag) - tags.begin()) +
           1;
  };

  // Bounding box of each entity (Gmsh uses them for its search structures).
  std::vector<Vec3d> lo(tags.size(), Vec3d{0, 0, 0}), hi(tags.size(), Vec3d{0, 0, 0});
  std::vector<bool> seen(tags.size(), false);
  for (size_t t = 0; t < nt; ++t) {
    const auto e = static_cast<size_t>(entity_of(region_of(t)) - 1);
    for (int32_t v : mesh.tets[t]) {
      const Vec3d p = mesh.rest_positions[v];
      if (!seen[e]) {
        lo[e] = hi[e] = p;
        seen[e] = true;
      }
      for (int k = 0; k < 3; ++k) {
        lo[e][k] = std::min(lo[e][k], p[k]);
        hi[e][k] = std::max(hi[e][k], p[k]);
      }
    }
  }

  MshOut out(binary);
  out.text(binary ? "$MeshFormat\n4.1 1 8\n" : "$MeshFormat\n4.1 0 8\n");
  if (binary) {
    append_raw(out.str(), int32_t{1});  // endianness marker
    out.text("\n");
  }
  out.text("$EndMeshFormat\n");

  // Physical names (always ASCII): the named regions with a writable tag.
  std::vector<const Region*> named;
  for (const Region& r : mesh.regions)
    if (r.tag > 0 && !r.name.empty()) named.push_back(&r);
  if (!named.empty()) {
    std::string s = "$PhysicalNames\n" + std::to_string(named.size()) + "\n";
    for (const Region* r : named)
      s += "3 " + std::to_string(r->tag) + " " + quoted_name(r->name) + "\n";
    out.text(s + "$EndPhysicalNames\n");
  }

  out.text("$Entities\n");
  out.size(0);
  out.size(0);
  out.size(0);
  out.size(tags.size());
  out.end_record();
  for (size_t e = 0; e < tags.size(); ++e) {
    out.i32(static_cast<int32_t>(e + 1));
    for (int k = 0; k < 3; ++k) out.real(lo[e][k]);
    for (int k = 0; k < 3; ++k) out.real(hi[e][k]);
    out.size(tags[e] > 0 ? 1 : 0);
    if (tags[e] > 0) out.i32(tags[e]);
    out.size(0);  // no bounding surfaces: we write volumes only
    out.end_record();
  }
  out.end_section("$EndEntities\n");

  // All nodes in one block on the first volume entity, tagged 1..n in mesh order.
  out.text("$Nodes\n");
  out.size(nv > 0 ? 1 : 0);
  out.size(nv);
  out.size(nv > 0 ? 1 : 0);
  out.size(nv);
  out.end_record();
  if (nv > 0) {
    out.i32(3);
    out.i32(1);
    out.i32(0);
    out.size(nv);
    out.end_record();
    for (size_t v = 0; v < nv; ++v) {
      out.size(v + 1);
      out.end_record();
    }
    for (const Vec3d& p : mesh.rest_positions) {
      out.real(p.x);
      out.real(p.y);
      out.real(p.z);
      out.end_record();
    }
  }
  out.end_section("$EndNodes\n");

  // One element block per run of equal tags, so the tetrahedra keep their order on reading.
  size_t nblocks = 0;
  for (size_t t = 0; t < nt; ++t)
    if (t == 0 || region_of(t) != region_of(t - 1)) ++nblocks;
  out.text("$Elements\n");
  out.size(nblocks);
  out.size(nt);
  out.size(nt > 0 ? 1 : 0);
  out.size(nt);
  out.end_record();
  for (size_t t = 0; t < nt;) {
    size_t end = t + 1;
    while (end < nt && region_of(end) == region_of(t)) ++end;
    out.i32(3);
    out.i32(entity_of(region_of(t)));
    out.i32(4);  // 4-node tetrahedron
    out.size(end - t);
    out.end_record();
    for (; t < end; ++t) {
      out.size(t + 1);
      for (int32_t v : mesh.tets[t]) out.size(static_cast<uint64_t>(v) + 1);
      out.end_record();
    }
  }
  out.end_section("$EndElements\n");
  return io_detail::write_file(path, out.str());
}

}  // namespace zona
