// Isosurface stuffing (after Labelle and Shewchuk, SIGGRAPH 2007) and interface cutting for the
// cell mesh generator.
//
// Both passes work on a tetrahedral mesh and one surface:
//  1. signs: each vertex is inside (-), on (0) or outside (+) the surface;
//  2. warping: a vertex closer to a crossing than alpha times the crossing edge's length is
//     snapped onto the crossing and becomes a zero vertex (alpha = 0.24799 on axis-aligned
//     lattice edges, 0.40173 on the others: the paper's values for its 10.7 degree bound), so
//     the remaining cut vertices sit well inside their edges;
//  3. splitting: every tetrahedron with both - and + vertices is cut along the polygon of its
//     cut vertices and zero vertices. Instead of the paper's stencil tables, the pieces are
//     built from two local rules, which is what makes neighbours agree:
//       - each triangular face is triangulated by its own cut vertices only: a cut quadrilateral
//         takes its shorter diagonal (ties: the diagonal at the smallest vertex index), so the
//         two tetrahedra that share a face always split it the same way;
//       - each side of the cut (a convex polytope with at most 6 vertices) is coned from the
//         vertex that gives the best worst dihedral angle; a polytope that no vertex can cone
//         (the prism whose three quadrilateral diagonals twist around it) gets a Steiner vertex
//         at its centre. The free choice of the cut quadrilateral's diagonal (2-2 case) is made
//         the same way, by quality.
// Choosing by measured quality rather than the paper's parity rule keeps the code small; the
// generator's tests check the resulting dihedral angles on many sizes and gradings.
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "engine/mesh/mesh_generate_internal.h"

namespace zona::mesh_gen {

double Ellipsoid::crossing(Vec3d inside, Vec3d outside) const {
  const Vec3d p{inside.x / semi_axes.x, inside.y / semi_axes.y, inside.z / semi_axes.z};
  const Vec3d o{outside.x / semi_axes.x, outside.y / semi_axes.y, outside.z / semi_axes.z};
  const Vec3d d = o - p;
  // |p + t d|^2 = 1: dd t^2 + 2 b t + c = 0 with c < 0, so exactly one root is positive.
  const double dd = dot(d, d), b = dot(p, d), c = dot(p, p) - 1.0;
  if (!(dd > 0)) return 0.5;
  const double root = std::sqrt(std::max(0.0, b * b - dd * c));
  // The two algebraically equal forms avoid cancellation for either sign of b.
  const double t = b <= 0 ? (root - b) / dd : -c / (b + root);
  return std::clamp(t, 0.0, 1.0);
}

double Ellipsoid::min_semi_axis() const {
  return std::min(semi_axes.x, std::min(semi_axes.y, semi_axes.z));
}

double tet_min_sine(Vec3d a, Vec3d b, Vec3d c, Vec3d d) {
  const double volume = tet_signed_volume(a, b, c, d);
  if (!(volume > 0)) return -1.0;
  const Vec3d p[4] = {a, b, c, d};
  // Face areas, face f opposite vertex f.
  double area[4];
  area[0] = 0.5 * norm(cross(c - b, d - b));
  area[1] = 0.5 * norm(cross(c - a, d - a));
  area[2] = 0.5 * norm(cross(b - a, d - a));
  area[3] = 0.5 * norm(cross(b - a, c - a));
  // sin(theta_ij) = 3 V |e_ij| / (2 A_k A_l): edge ij is shared by the faces opposite k and l.
  double worst = 1.0;
  for (int i = 0; i < 4; ++i)
    for (int j = i + 1; j < 4; ++j) {
      int k = 0;
      while (k == i || k == j) ++k;
      const int m = 6 - i - j - k;
      const double denominator = 2.0 * area[k] * area[m];
      if (!(denominator > 0)) return 0.0;
      worst = std::min(worst, 3.0 * volume * norm(p[i] - p[j]) / denominator);
    }
  return worst;
}

namespace {

constexpr double kAlphaLong = 0.24799;   // axis-aligned lattice edges
constexpr double kAlphaShort = 0.40173;  // all other edges
constexpr double kWarpAltitudeFraction = 0.5;
// A snap that would leave a neighbouring tetrahedron below these dihedral sines (about 5 and
// 5.7 degrees: one that stays whole, one that will be cut) is refused. Never binding on the
// uniform lattice (the paper's bound there is 10.7 degrees); at octree transitions it keeps a
// snap from flattening a tetrahedron whose pieces would then be slivers. (Measured on 1200
// random specs: without the second floor 1 in 1200 meshes had a 5.7 degree element left.)
constexpr double kWarpMinSine = 0.0872;
constexpr double kWarpMinSineCut = 0.1;
// A cone tetrahedron whose smallest dihedral sine is below this is treated as flat: its apex
// lies in the plane of the face (or the polytope is not star-shaped from it).
constexpr double kFlatSine = 1e-7;
// Below this worst sine (about 5.7 degrees) a Steiner vertex is tried as well.
constexpr double kTrySteinerSine = 0.1;

constexpr int kEdgeVerts[6][2] = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}};
constexpr int kEdgeOf[4][4] = {{-1, 0, 1, 2}, {0, -1, 3, 4}, {1, 3, -1, 5}, {2, 4, 5, -1}};
// Faces of a positively oriented tetrahedron, outward, face f opposite vertex f.
constexpr int kFaces[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};

constexpr int kMaxPoints = 12;  // 4 vertices, 6 edge cuts, 2 Steiner vertices
constexpr int kSteiner0 = 10;

// One tetrahedron with its cut vertices, in local indices: 0-3 the vertices, 4-9 the cut
// vertices of edges 0-5 (when present), 10-11 Steiner vertices.
struct Local {
  Vec3d p[kMaxPoints];
  int64_t order[kMaxPoints];  // global index: the tie-break that neighbours share
  int8_t sign[kMaxPoints];
  int8_t cut[6];              // local index of edge e's cut vertex, or -1
};

struct Tri {
  uint8_t v[3];
};

struct Piece {
  uint8_t v[4];
  int8_t side;  // -1 inside, +1 outside, 0 to be tagged by its centroid
};

struct SplitResult {
  Piece pieces[48];
  int count = 0;
  Vec3d steiner[2];
  int steiner_count = 0;
};

bool axis_aligned(Vec3d a, Vec3d b) {
  return (a.x == b.x ? 1 : 0) + (a.y == b.y ? 1 : 0) + (a.z == b.z ? 1 : 0) == 2;
}

double dist2(Vec3d a, Vec3d b) {
  const Vec3d d = a - b;
  return dot(d, d);
}

// Triangulates face (x, y, z) (outward order) with the cut vertices on its edges.
int face_triangles(const Local& t, int x, int y, int z, Tri* out) {
  const int v[3] = {x, y, z};
  int m[3];
  int cuts = 0;
  for (int i = 0; i < 3; ++i) {
    m[i] = t.cut[kEdgeOf[v[i]][v[(i + 1) % 3]]];
    cuts += m[i] >= 0 ? 1 : 0;
  }
  auto u8 = [](int i) { return static_cast<uint8_t>(i); };
  if (cuts == 0) {
    out[0] = {{u8(x), u8(y), u8(z)}};
    return 1;
  }
  if (cuts == 1) {
    int r = 0;
    while (m[r] < 0) ++r;
    const int a = v[r], b = v[(r + 1) % 3], c = v[(r + 2) % 3], mm = m[r];
    out[0] = {{u8(a), u8(mm), u8(c)}};
    out[1] = {{u8(mm), u8(b), u8(c)}};
    return 2;
  }
  // Two cuts (three are impossible: the signs along a triangle change an even number of
  // times). Let a be the vertex between the two cut edges, the polygon a m1 b c m2.
  int r = 0;
  while (m[r] >= 0) ++r;  // edge (v[r], v[r+1]) is the uncut one
  const int a = v[(r + 2) % 3], b = v[r], c = v[(r + 1) % 3];
  const int m1 = m[(r + 2) % 3], m2 = m[(r + 1) % 3];
  out[0] = {{u8(a), u8(m1), u8(m2)}};
  const double d1 = dist2(t.p[m1], t.p[c]), d2 = dist2(t.p[b], t.p[m2]);
  bool diagonal_m1c;
  if (d1 != d2) {
    diagonal_m1c = d1 < d2;
  } else {
    const int64_t lowest = std::min(std::min(t.order[m1], t.order[c]),
                                    std::min(t.order[b], t.order[m2]));
    diagonal_m1c = lowest == t.order[m1] || lowest == t.order[c];
  }
  if (diagonal_m1c) {
    out[1] = {{u8(m1), u8(b), u8(c)}};
    out[2] = {{u8(m1), u8(c), u8(m2)}};
  } else {
    out[1] = {{u8(m1), u8(b), u8(m2)}};
    out[2] = {{u8(b), u8(c), u8(m2)}};
  }
  return 3;
}

// How to tetrahedralize one polytope: cone from `apex`, or from a Steiner vertex at `centre`
// when apex < 0.
struct Cone {
  int apex = -1;
  double score = -1;  // worst dihedral sine, < 0 when impossible
  Vec3d centre{0, 0, 0};
};

bool contains(const Tri& tri, int v) { return tri.v[0] == v || tri.v[1] == v || tri.v[2] == v; }

// Orients the boundary triangles outward (seen from the vertex centroid) and finds the best
// cone.
Cone best_cone(const Local& t, Tri* tris, int n) {
  uint32_t used = 0;
  for (int i = 0; i < n; ++i)
    for (int k = 0; k < 3; ++k) used |= 1u << tris[i].v[k];
  Vec3d centre{0, 0, 0};
  int used_count = 0;
  for (int v = 0; v < kMaxPoints; ++v)
    if (used & (1u << v)) {
      centre += t.p[v];
      ++used_count;
    }
  centre = centre / static_cast<double>(used_count);
  for (int i = 0; i < n; ++i) {
    Tri& tri = tris[i];
    if (tet_signed_volume(t.p[tri.v[0]], t.p[tri.v[1]], t.p[tri.v[2]], centre) > 0)
      std::swap(tri.v[1], tri.v[2]);
  }
  Cone best;
  best.centre = centre;
  for (int v = 0; v < kMaxPoints; ++v) {
    if (!(used & (1u << v))) continue;
    double worst = 1.0;
    for (int i = 0; i < n && worst >= kFlatSine; ++i) {
      if (contains(tris[i], v)) continue;
      const Tri& tri = tris[i];
      worst = std::min(worst, tet_min_sine(t.p[tri.v[0]], t.p[tri.v[2]], t.p[tri.v[1]], t.p[v]));
    }
    if (worst >= kFlatSine && worst > best.score) {
      best.apex = v;
      best.score = worst;
    }
  }
  if (best.score < kTrySteinerSine) {
    double worst = 1.0;
    for (int i = 0; i < n; ++i) {
      const Tri& tri = tris[i];
      worst = std::min(worst, tet_min_sine(t.p[tri.v[0]], t.p[tri.v[2]], t.p[tri.v[1]], centre));
    }
    if (worst >= kFlatSine && worst > best.score) {
      best.apex = -1;
      best.score = worst;
    }
  }
  return best;
}

void emit_cone(const Cone& cone, const Tri* tris, int n, int8_t side, SplitResult* out) {
  int apex = cone.apex;
  if (apex < 0) {
    apex = kSteiner0 + out->steiner_count;
    out->steiner[out->steiner_count++] = cone.centre;
  }
  for (int i = 0; i < n; ++i) {
    const Tri& tri = tris[i];
    if (contains(tri, apex)) continue;
    out->pieces[out->count++] = {
        {tri.v[0], tri.v[2], tri.v[1], static_cast<uint8_t>(apex)}, side};
  }
}

enum class SplitMode {
  kInside,   // keep the inside part only
  kBoth,     // keep both parts
  kWhole,    // the cuts do not form a closed interface: split the whole tetrahedron
};

// Splits one tetrahedron. Returns false when a polytope cannot be tetrahedralized (never
// expected; reported as an internal error).
bool split_tet(Local& t, SplitMode mode, SplitResult* out) {
  Tri faces[12];
  int face_count = 0;
  for (const auto& f : kFaces) face_count += face_triangles(t, f[0], f[1], f[2], faces + face_count);

  if (mode == SplitMode::kWhole) {
    const Cone cone = best_cone(t, faces, face_count);
    if (cone.score < kFlatSine) return false;
    emit_cone(cone, faces, face_count, 0, out);
    return true;
  }

  // The cut polygon: cut vertices and zero vertices. It has 4 corners only when two vertices
  // lie on each side; then either diagonal may split it and quality decides.
  int corners[6];
  int corner_count = 0;
  for (int v = 0; v < 4; ++v)
    if (t.sign[v] == 0) corners[corner_count++] = v;
  for (int e = 0; e < 6; ++e)
    if (t.cut[e] >= 0) corners[corner_count++] = t.cut[e];
  Tri cut_options[2][2];
  int option_count = 1, cut_tri_count = 1;
  auto u8 = [](int i) { return static_cast<uint8_t>(i); };
  if (corner_count == 3) {
    cut_options[0][0] = {{u8(corners[0]), u8(corners[1]), u8(corners[2])}};
  } else if (corner_count == 4) {
    int in[2], outv[2], ni = 0, no = 0;
    for (int v = 0; v < 4; ++v) {
      if (t.sign[v] < 0) in[ni++] = v;
      if (t.sign[v] > 0) outv[no++] = v;
    }
    if (ni != 2 || no != 2) return false;
    const int c11 = t.cut[kEdgeOf[in[0]][outv[0]]], c12 = t.cut[kEdgeOf[in[0]][outv[1]]];
    const int c22 = t.cut[kEdgeOf[in[1]][outv[1]]], c21 = t.cut[kEdgeOf[in[1]][outv[0]]];
    // Cyclic order c11 c12 c22 c21: consecutive corners share a tetrahedron vertex.
    cut_options[0][0] = {{u8(c11), u8(c12), u8(c22)}};
    cut_options[0][1] = {{u8(c11), u8(c22), u8(c21)}};
    cut_options[1][0] = {{u8(c11), u8(c12), u8(c21)}};
    cut_options[1][1] = {{u8(c12), u8(c22), u8(c21)}};
    option_count = 2;
    cut_tri_count = 2;
  } else {
    return false;
  }

  // Each side's boundary: its face triangles (the side of a triangle is the sign of any of its
  // non-zero corners) plus the cut triangles.
  auto side_of = [&](const Tri& tri) {
    for (int k = 0; k < 3; ++k)
      if (t.sign[tri.v[k]] != 0) return static_cast<int>(t.sign[tri.v[k]]);
    return 0;
  };
  struct Option {
    Tri tris[2][16];
    int n[2] = {0, 0};
    Cone cone[2];
    double score = -1;
  };
  Option options[2];
  const int sides = mode == SplitMode::kBoth ? 2 : 1;
  int best = -1;
  for (int o = 0; o < option_count; ++o) {
    Option& opt = options[o];
    opt.score = 1.0;
    for (int s = 0; s < sides; ++s) {
      const int sign = s == 0 ? -1 : 1;
      for (int i = 0; i < face_count; ++i)
        if (side_of(faces[i]) == sign) opt.tris[s][opt.n[s]++] = faces[i];
      for (int i = 0; i < cut_tri_count; ++i) opt.tris[s][opt.n[s]++] = cut_options[o][i];
      opt.cone[s] = best_cone(t, opt.tris[s], opt.n[s]);
      opt.score = std::min(opt.score, opt.cone[s].score);
    }
    if (opt.score >= kFlatSine && (best < 0 || opt.score > options[best].score)) best = o;
  }
  if (best < 0) return false;
  for (int s = 0; s < sides; ++s)
    emit_cone(options[best].cone[s], options[best].tris[s], options[best].n[s],
              static_cast<int8_t>(s == 0 ? -1 : 1), out);
  return true;
}

int8_t sign_of(double value) { return value < 0 ? -1 : (value > 0 ? 1 : 0); }

// Snaps vertices that lie too close to a crossing onto it (step 2 of the file comment).
// `may_cut(a, b)` says whether edge (a, b) may carry a cut vertex. Returns the count.
//
// A snap is also limited to kWarpAltitudeFraction of the vertex's smallest altitude in its
// tetrahedra. On the uniform lattice this never binds (the paper's snaps move a vertex at most
// 49 % of the BCC altitude); at octree transitions a vertex joins long and short edges, and a
// snap along a long edge could otherwise push it through a small neighbour. Snaps are applied
// one at a time and refused when they would leave a neighbour nearly flat.
template <class MayCut>
int64_t warp_vertices(std::vector<Vec3d>& p, std::vector<int8_t>& sign,
                      const std::vector<Tet>& tets, const Ellipsoid& surface, MayCut&& may_cut) {
  struct Candidate {
    int32_t vertex;
    double distance;
    Vec3d target;
  };
  std::vector<Candidate> candidates;
  std::vector<int32_t> slot(p.size(), -1);
  auto offer = [&](int32_t v, double distance, Vec3d target) {
    if (slot[v] < 0) {
      slot[v] = static_cast<int32_t>(candidates.size());
      candidates.push_back({v, distance, target});
    } else if (distance < candidates[slot[v]].distance) {  // strict: the first of equals wins
      candidates[slot[v]].distance = distance;
      candidates[slot[v]].target = target;
    }
  };
  for (const Tet& tet : tets) {
    const int8_t s0 = sign[tet[0]], s1 = sign[tet[1]], s2 = sign[tet[2]], s3 = sign[tet[3]];
    const bool has_in = s0 < 0 || s1 < 0 || s2 < 0 || s3 < 0;
    const bool has_out = s0 > 0 || s1 > 0 || s2 > 0 || s3 > 0;
    if (!has_in || !has_out) continue;
    for (const auto& e : kEdgeVerts) {
      int32_t a = tet[e[0]], b = tet[e[1]];
      if (sign[a] * sign[b] >= 0 || !may_cut(a, b)) continue;
      if (sign[a] > 0) std::swap(a, b);  // a inside
      const double f = surface.crossing(p[a], p[b]);
      const Vec3d target = p[a] + f * (p[b] - p[a]);
      const double length = norm(p[b] - p[a]);
      const double alpha = axis_aligned(p[a], p[b]) ? kAlphaLong : kAlphaShort;
      if (f < alpha) offer(a, f * length, target);
      if (1.0 - f < alpha) offer(b, (1.0 - f) * length, target);
    }
  }
  if (candidates.empty()) return 0;

  // The tetrahedra around each candidate, as compressed lists.
  std::vector<int32_t> offset(candidates.size() + 1, 0);
  for (const Tet& tet : tets)
    for (int v = 0; v < 4; ++v)
      if (slot[tet[v]] >= 0) ++offset[slot[tet[v]] + 1];
  for (size_t i = 0; i < candidates.size(); ++i) offset[i + 1] += offset[i];
  std::vector<int32_t> incident(static_cast<size_t>(offset.back()));
  {
    std::vector<int32_t> fill(offset.begin(), offset.end() - 1);
    for (size_t t = 0; t < tets.size(); ++t)
      for (int v = 0; v < 4; ++v)
        if (slot[tets[t][v]] >= 0) incident[fill[slot[tets[t][v]]]++] = static_cast<int32_t>(t);
  }

  // The altitude bound uses the lattice positions (before any snap), as on the uniform
  // lattice the paper's simultaneous snaps are safe.
  std::vector<double> altitude(candidates.size(), std::numeric_limits<double>::infinity());
  for (size_t i = 0; i < candidates.size(); ++i)
    for (int j = offset[i]; j < offset[i + 1]; ++j) {
      const Tet& tet = tets[incident[j]];
      int k = 0;
      while (tet[k] != candidates[i].vertex) ++k;
      const int* f = kFaces[k];
      const double six_volume =
          6.0 * std::abs(tet_signed_volume(p[tet[0]], p[tet[1]], p[tet[2]], p[tet[3]]));
      const double twice_area =
          norm(cross(p[tet[f[1]]] - p[tet[f[0]]], p[tet[f[2]]] - p[tet[f[0]]]));
      if (twice_area > 0) altitude[i] = std::min(altitude[i], six_volume / twice_area);
    }

  // Snap one vertex at a time, in discovery order, checked against the current positions of
  // its neighbours: two snaps that are each safe alone can still fold a tetrahedron between them.
  int64_t warped = 0;
  for (size_t i = 0; i < candidates.size(); ++i) {
    const Candidate& c = candidates[i];
    const int32_t v = c.vertex;
    if (c.distance > kWarpAltitudeFraction * altitude[i]) continue;
    bool safe = true;
    for (int j = offset[i]; j < offset[i + 1] && safe; ++j) {
      const Tet& tet = tets[incident[j]];
      int k = 0;
      while (tet[k] != v) ++k;
      Vec3d q[4] = {p[tet[0]], p[tet[1]], p[tet[2]], p[tet[3]]};
      q[k] = c.target;
      // A tetrahedron that will be kept whole keeps this shape; one with an outside vertex
      // will be cut, and a nearly flat one would only give nearly flat pieces.
      bool kept_whole = true;
      for (int m = 0; m < 4; ++m) kept_whole &= m == k || sign[tet[m]] <= 0;
      const double quality = tet_min_sine(q[0], q[1], q[2], q[3]);
      safe = quality >= (kept_whole ? kWarpMinSine : kWarpMinSineCut);
    }
    if (!safe) continue;
    p[v] = c.target;
    sign[v] = 0;
    ++warped;
  }
  return warped;
}

// Fills `t` for tetrahedron `tet`, creating (once per edge) the cut vertices of the edges for
// which cut(a, b) is true.
template <class Cut>
void load_local(Local& t, const Tet& tet, std::vector<Vec3d>& p, const std::vector<int8_t>& sign,
                const Ellipsoid& surface, IndexMap& cut_map, Cut&& cut, int64_t* new_cuts) {
  for (int v = 0; v < 4; ++v) {
    t.p[v] = p[tet[v]];
    t.order[v] = tet[v];
    t.sign[v] = sign[tet[v]];
  }
  for (int e = 0; e < 6; ++e) {
    t.cut[e] = -1;
    int32_t a = tet[kEdgeVerts[e][0]], b = tet[kEdgeVerts[e][1]];
    if (sign[a] * sign[b] >= 0 || !cut(a, b)) continue;
    bool inserted = false;
    const int32_t id = cut_map.find_or_insert(edge_key(a, b), static_cast<int32_t>(p.size()),
                                              &inserted);
    if (inserted) {
      if (sign[a] > 0) std::swap(a, b);
      const double f = surface.crossing(p[a], p[b]);
      p.push_back(p[a] + f * (p[b] - p[a]));
      ++*new_cuts;
    }
    const int local = 4 + e;
    t.cut[e] = static_cast<int8_t>(local);
    t.p[local] = p[id];
    t.order[local] = id;
    t.sign[local] = 0;
  }
}

// Global indices of a split's pieces; appends its Steiner vertices.
std::array<int32_t, kMaxPoints> global_ids(const Tet& tet, const Local& t,
                                           const SplitResult& r, std::vector<Vec3d>& p) {
  std::array<int32_t, kMaxPoints> id{};
  for (int v = 0; v < 4; ++v) id[v] = tet[v];
  for (int e = 0; e < 6; ++e)
    if (t.cut[e] >= 0) id[4 + e] = static_cast<int32_t>(t.order[4 + e]);
  for (int s = 0; s < r.steiner_count; ++s) {
    id[kSteiner0 + s] = static_cast<int32_t>(p.size());
    p.push_back(r.steiner[s]);
  }
  return id;
}

Vec3d centroid(const std::vector<Vec3d>& p, const Tet& t) {
  return 0.25 * (p[t[0]] + p[t[1]] + p[t[2]] + p[t[3]]);
}

}  // namespace

Result<WorkMesh> stuff_inside(Lattice lattice, const Ellipsoid& surface, int32_t region,
                              CutStats* stats) {
  CutStats local_stats;
  CutStats& st = stats ? *stats : local_stats;
  WorkMesh mesh;
  mesh.positions = std::move(lattice.positions);
  std::vector<Vec3d>& p = mesh.positions;
  const size_t lattice_vertices = p.size();
  std::vector<int8_t> sign(lattice_vertices);
  for (size_t i = 0; i < lattice_vertices; ++i) sign[i] = sign_of(surface.value(p[i]));

  auto any = [](int32_t, int32_t) { return true; };
  st.warped_vertices += warp_vertices(p, sign, lattice.tets, surface, any);

  // Relevant cells hug the surface, so most lattice tetrahedra are kept (about 88 %).
  mesh.tets.reserve(lattice.tets.size());
  mesh.pristine.reserve(lattice.tets.size());
  IndexMap cut_map(1024);
  for (const Tet& tet : lattice.tets) {
    int in = 0, out = 0;
    for (int v = 0; v < 4; ++v) {
      in += sign[tet[v]] < 0 ? 1 : 0;
      out += sign[tet[v]] > 0 ? 1 : 0;
    }
    if (out == 0) {
      // Inside (or all four vertices on the surface: then the centroid decides).
      if (in == 0 && surface.value(centroid(p, tet)) >= 0) continue;
      mesh.tets.push_back(tet);
      mesh.pristine.push_back(1);
      continue;
    }
    if (in == 0) continue;
    Local t;
    load_local(t, tet, p, sign, surface, cut_map, any, &st.cut_vertices);
    SplitResult r;
    if (!split_tet(t, SplitMode::kInside, &r))
      return make_error("mesh generator: cannot split lattice tetrahedron (%d %d %d %d) at the "
                        "surface (internal error)",
                        tet[0], tet[1], tet[2], tet[3]);
    const auto id = global_ids(tet, t, r, p);
    st.steiner_vertices += r.steiner_count;
    ++st.cut_tets;
    for (int i = 0; i < r.count; ++i) {
      const Piece& piece = r.pieces[i];
      mesh.tets.push_back({id[piece.v[0]], id[piece.v[1]], id[piece.v[2]], id[piece.v[3]]});
      mesh.pristine.push_back(0);
    }
  }
  mesh.region.assign(mesh.tets.size(), region);
  return mesh;
}

Result<CutStats> cut_interface(WorkMesh& mesh, const Ellipsoid& surface, double max_edge,
                               int32_t inside_region, int32_t outside_region) {
  CutStats st;
  std::vector<Vec3d>& p = mesh.positions;
  const size_t n = p.size();
  std::vector<int8_t> sign(n);
  for (size_t i = 0; i < n; ++i) sign[i] = sign_of(surface.value(p[i]));

  // The interface is cut only inside the resolved zone: vertices all of whose tetrahedra are
  // still lattice tetrahedra no longer than max_edge. Cutting an edge needs both ends in it,
  // so warping never moves a vertex of a tetrahedron that is left whole.
  std::vector<uint8_t> zone(n, 1);
  const double max_edge2 = max_edge * max_edge;
  for (size_t t = 0; t < mesh.tets.size(); ++t) {
    const Tet& tet = mesh.tets[t];
    bool ok = mesh.pristine[t] != 0;
    for (int e = 0; e < 6 && ok; ++e)
      ok = dist2(p[tet[kEdgeVerts[e][0]]], p[tet[kEdgeVerts[e][1]]]) <= max_edge2;
    if (!ok)
      for (int v = 0; v < 4; ++v) zone[tet[v]] = 0;
  }
  auto in_zone = [&](int32_t a, int32_t b) { return zone[a] && zone[b]; };
  st.warped_vertices = warp_vertices(p, sign, mesh.tets, surface, in_zone);

  auto tag = [&](int8_t side, int32_t old_tag, const Tet& t) {
    if (side == 0) side = surface.value(centroid(p, t)) < 0 ? -1 : 1;
    const int32_t wanted = side < 0 ? inside_region : outside_region;
    return wanted < 0 ? old_tag : wanted;
  };

  WorkMesh out;
  out.tets.reserve(mesh.tets.size() + mesh.tets.size() / 8);
  out.region.reserve(out.tets.capacity());
  out.pristine.reserve(out.tets.capacity());
  IndexMap cut_map(1024);
  for (size_t ti = 0; ti < mesh.tets.size(); ++ti) {
    const Tet tet = mesh.tets[ti];
    const int32_t old_tag = mesh.region[ti];
    int in = 0, outside = 0, crossing = 0, cut = 0;
    for (int v = 0; v < 4; ++v) {
      in += sign[tet[v]] < 0 ? 1 : 0;
      outside += sign[tet[v]] > 0 ? 1 : 0;
    }
    if (in > 0 && outside > 0)
      for (const auto& e : kEdgeVerts)
        if (sign[tet[e[0]]] * sign[tet[e[1]]] < 0) {
          ++crossing;
          cut += in_zone(tet[e[0]], tet[e[1]]) ? 1 : 0;
        }
    if (cut == 0) {
      if (crossing > 0) ++st.centroid_tets;
      out.tets.push_back(tet);
      out.region.push_back(tag(0, old_tag, tet));
      out.pristine.push_back(mesh.pristine[ti]);
      continue;
    }
    Local t;
    load_local(t, tet, p, sign, surface, cut_map, in_zone, &st.cut_vertices);
    SplitResult r;
    const SplitMode mode = cut == crossing ? SplitMode::kBoth : SplitMode::kWhole;
    if (!split_tet(t, mode, &r))
      return make_error("mesh generator: cannot split tetrahedron %zu at an interface (internal "
                        "error)",
                        ti);
    const auto id = global_ids(tet, t, r, p);
    st.steiner_vertices += r.steiner_count;
    if (mode == SplitMode::kBoth) ++st.cut_tets;
    else ++st.centroid_tets;
    for (int i = 0; i < r.count; ++i) {
      const Piece& piece = r.pieces[i];
      const Tet sub{id[piece.v[0]], id[piece.v[1]], id[piece.v[2]], id[piece.v[3]]};
      out.tets.push_back(sub);
      out.region.push_back(tag(piece.side, old_tag, sub));
      out.pristine.push_back(0);
    }
  }
  mesh.tets = std::move(out.tets);
  mesh.region = std::move(out.region);
  mesh.pristine = std::move(out.pristine);
  return st;
}

void remove_unreferenced(WorkMesh& mesh) {
  std::vector<int32_t> remap(mesh.positions.size(), -1);
  for (const Tet& t : mesh.tets)
    for (int v = 0; v < 4; ++v) remap[t[v]] = 0;
  int32_t next = 0;
  for (size_t i = 0; i < remap.size(); ++i)
    if (remap[i] == 0) {
      mesh.positions[next] = mesh.positions[i];
      remap[i] = next++;
    }
  mesh.positions.resize(static_cast<size_t>(next));
  for (Tet& t : mesh.tets)
    for (int v = 0; v < 4; ++v) t[v] = remap[t[v]];
}

}  // namespace zona::mesh_gen
