// Background lattice of the cell mesh generator: body-centred cubic (BCC) tetrahedra on a
// 2:1-balanced octree of cubes, graded towards a refinement point.
//
// Uniform part: the BCC lattice is the cube corners plus the cube centres; each tetrahedron
// joins two neighbouring centres (a "red"-"black" pair across a shared face) with one edge of
// that face, so every interior face carries 4 tetrahedra (12 per cube, dihedral angles 60 and
// 90 degrees). Grading: where a face separates cells of different sizes, or one of its edges
// touches a smaller cell, the two half-tetrahedra on either side of the face are kept apart and
// joined to the face centre (and split at edge midpoints) instead. With 2:1 balance over all 26
// neighbours, every face and edge is split the same way from both sides, so the result is
// conforming by construction.
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "engine/mesh/mesh_generate_internal.h"

namespace zona::mesh_gen {

// ---- IndexMap -------------------------------------------------------------------------------

namespace {
constexpr uint64_t kEmptyKey = ~uint64_t{0};

// splitmix64 finaliser: lattice keys are highly structured, so scramble all bits.
inline uint64_t mix(uint64_t x) {
  x ^= x >> 30;
  x *= 0xbf58476d1ce4e5b9ULL;
  x ^= x >> 27;
  x *= 0x94d049bb133111ebULL;
  x ^= x >> 31;
  return x;
}
}  // namespace

IndexMap::IndexMap(size_t expected_size) {
  size_t capacity = 16;
  while (capacity < 2 * expected_size) capacity *= 2;
  keys_.assign(capacity, kEmptyKey);
  values_.assign(capacity, -1);
  mask_ = capacity - 1;
}

int32_t IndexMap::find(uint64_t key) const {
  for (size_t i = mix(key) & mask_;; i = (i + 1) & mask_) {
    if (keys_[i] == key) return values_[i];
    if (keys_[i] == kEmptyKey) return -1;
  }
}

int32_t IndexMap::find_or_insert(uint64_t key, int32_t value, bool* inserted) {
  if (2 * (size_ + 1) > keys_.size()) grow();
  for (size_t i = mix(key) & mask_;; i = (i + 1) & mask_) {
    if (keys_[i] == key) {
      *inserted = false;
      return values_[i];
    }
    if (keys_[i] == kEmptyKey) {
      keys_[i] = key;
      values_[i] = value;
      ++size_;
      *inserted = true;
      return value;
    }
  }
}

void IndexMap::grow() {
  std::vector<uint64_t> keys(keys_.size() * 2, kEmptyKey);
  std::vector<int32_t> values(keys.size(), -1);
  const size_t mask = keys.size() - 1;
  for (size_t j = 0; j < keys_.size(); ++j) {
    if (keys_[j] == kEmptyKey) continue;
    size_t i = mix(keys_[j]) & mask;
    while (keys[i] != kEmptyKey) i = (i + 1) & mask;
    keys[i] = keys_[j];
    values[i] = values_[j];
  }
  keys_.swap(keys);
  values_.swap(values);
  mask_ = mask;
}

// ---- Octree ---------------------------------------------------------------------------------

namespace {

// Points are keyed by integer coordinates in half-units of the finest cell (so that centres
// of the finest cells are integers too), 21 bits per axis.
constexpr int kKeyBits = 21;
constexpr int64_t kKeyLimit = int64_t{1} << kKeyBits;

using I3 = std::array<int64_t, 3>;

inline uint64_t point_key(const I3& x) {
  return static_cast<uint64_t>(x[0]) | (static_cast<uint64_t>(x[1]) << kKeyBits) |
         (static_cast<uint64_t>(x[2]) << (2 * kKeyBits));
}

struct Cell {
  int32_t node;
  int level;
  I3 index;  // integer cell coordinates at `level`
};

// A forest of octrees over a grid of root cubes. Node i's children are the 8 consecutive nodes
// from child_[i] (-1: a leaf); child c covers octant (c & 1, c >> 1 & 1, c >> 2 & 1).
class Octree {
 public:
  Octree(const I3& roots) : roots_(roots), child_(static_cast<size_t>(roots[0] * roots[1] * roots[2]), -1) {}

  struct Hit {
    int32_t node;  // -1 outside the root grid
    int level;     // level of `node` (<= the level asked for)
  };

  // The node at `level` covering cell `x`, or the leaf above it when the tree is coarser there.
  Hit find(int level, const I3& x) const {
    I3 r;
    for (int a = 0; a < 3; ++a) {
      r[a] = x[a] >> level;  // arithmetic shift: negative indices stay negative
      if (r[a] < 0 || r[a] >= roots_[a]) return {-1, 0};
    }
    int32_t node = static_cast<int32_t>(r[0] + roots_[0] * (r[1] + roots_[1] * r[2]));
    for (int l = 0; l < level; ++l) {
      const int32_t first = child_[node];
      if (first < 0) return {node, l};
      const int bit = level - 1 - l;
      const int c = static_cast<int>(((x[0] >> bit) & 1) | (((x[1] >> bit) & 1) << 1) |
                                     (((x[2] >> bit) & 1) << 2));
      node = first + c;
    }
    return {node, level};
  }

  bool is_leaf(int32_t node) const { return child_[node] < 0; }
  int32_t first_child(int32_t node) const { return child_[node]; }
  size_t node_count() const { return child_.size(); }
  const I3& roots() const { return roots_; }

  int32_t split(int32_t node) {
    const int32_t first = static_cast<int32_t>(child_.size());
    child_[node] = first;
    child_.insert(child_.end(), 8, -1);
    return first;
  }

  static Cell child_cell(const Cell& parent, int32_t first, int c) {
    return {first + c, parent.level + 1,
            {2 * parent.index[0] + (c & 1), 2 * parent.index[1] + ((c >> 1) & 1),
             2 * parent.index[2] + ((c >> 2) & 1)}};
  }

 private:
  I3 roots_;
  std::vector<int32_t> child_;
};

class LatticeBuilder {
 public:
  LatticeBuilder(const LatticeSpec& spec, const I3& roots, Vec3d origin)
      : spec_(spec), tree_(roots), origin_(origin),
        unit_(spec.coarse_size / static_cast<double>(int64_t{1} << (spec.max_level + 1))) {}

  double cell_size(int level) const {
    return spec_.coarse_size / static_cast<double>(int64_t{1} << level);
  }

  // A cell matters when its box grown by one cell size reaches the ellipsoid: only then can a
  // tetrahedron it emits (which may reach into the next cell) cross the surface.
  bool relevant(const Cell& c) const {
    const double s = cell_size(c.level);
    double r2 = 0;
    for (int a = 0; a < 3; ++a) {
      const double lo = origin_[a] + static_cast<double>(c.index[a]) * s - s;
      const double hi = lo + 3 * s;
      const double closest = std::clamp(0.0, lo, hi) / spec_.semi_axes[a];
      r2 += closest * closest;
    }
    return r2 <= 1.0;
  }

  bool wants_split(const Cell& c) const {
    if (c.level >= spec_.max_level || !relevant(c)) return false;
    const double s = cell_size(c.level);
    double d2 = 0;
    for (int a = 0; a < 3; ++a) {
      const double lo = origin_[a] + static_cast<double>(c.index[a]) * s;
      const double q = std::clamp(spec_.refine_center[a], lo, lo + s) - spec_.refine_center[a];
      d2 += q * q;
    }
    const double d = std::sqrt(d2);
    const double wanted = std::min(
        spec_.coarse_size,
        spec_.fine_size + spec_.grading * std::max(0.0, d - spec_.refine_radius));
    return s > wanted * (1 + 1e-9);
  }

  void refine() {
    std::vector<Cell> stack;
    const I3& n = tree_.roots();
    for (int64_t k = 0; k < n[2]; ++k)
      for (int64_t j = 0; j < n[1]; ++j)
        for (int64_t i = 0; i < n[0]; ++i) {
          stack.push_back({static_cast<int32_t>(i + n[0] * (j + n[1] * k)), 0, {i, j, k}});
          while (!stack.empty()) {
            const Cell c = stack.back();
            stack.pop_back();
            if (!wants_split(c)) continue;
            const int32_t first = tree_.split(c.node);
            for (int q = 7; q >= 0; --q) stack.push_back(Octree::child_cell(c, first, q));
          }
        }
  }

  // 2:1 balance over all 26 neighbours: a leaf may touch leaves at most one level coarser.
  void balance() {
    std::vector<Cell> queue;
    for_each_leaf([&](const Cell& c) { queue.push_back(c); });
    for (size_t head = 0; head < queue.size(); ++head) {
      const Cell c = queue[head];
      if (!tree_.is_leaf(c.node) || c.level < 2) continue;
      for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            if (dx == 0 && dy == 0 && dz == 0) continue;
            const I3 x{c.index[0] + dx, c.index[1] + dy, c.index[2] + dz};
            for (;;) {
              const Octree::Hit hit = tree_.find(c.level, x);
              if (hit.node < 0 || hit.level >= c.level - 1) break;
              const int shift = c.level - hit.level;
              const Cell coarse{hit.node, hit.level,
                                {x[0] >> shift, x[1] >> shift, x[2] >> shift}};
              const int32_t first = tree_.split(hit.node);
              for (int q = 0; q < 8; ++q) queue.push_back(Octree::child_cell(coarse, first, q));
            }
          }
    }
  }

  template <class F>
  void for_each_leaf(F&& f) const {
    std::vector<Cell> stack;
    const I3& n = tree_.roots();
    for (int64_t k = 0; k < n[2]; ++k)
      for (int64_t j = 0; j < n[1]; ++j)
        for (int64_t i = 0; i < n[0]; ++i) {
          stack.push_back({static_cast<int32_t>(i + n[0] * (j + n[1] * k)), 0, {i, j, k}});
          while (!stack.empty()) {
            const Cell c = stack.back();
            stack.pop_back();
            const int32_t first = tree_.first_child(c.node);
            if (first < 0) {
              f(c);
              continue;
            }
            for (int q = 7; q >= 0; --q) stack.push_back(Octree::child_cell(c, first, q));
          }
        }
  }

  Lattice emit() {
    int64_t relevant_leaves = 0;
    for_each_leaf([&](const Cell& c) { relevant_leaves += relevant(c) ? 1 : 0; });
    lattice_.leaf_count = relevant_leaves;
    // About 2 vertices per cell (corner and centre), more at octree transitions.
    map_ = IndexMap(static_cast<size_t>(relevant_leaves) * 5 / 2);
    lattice_.positions.reserve(static_cast<size_t>(relevant_leaves) * 5 / 2);
    lattice_.tets.reserve(static_cast<size_t>(relevant_leaves) * 13);
    for_each_leaf([&](const Cell& c) {
      if (relevant(c)) emit_cell(c);
    });
    return std::move(lattice_);
  }

 private:
  int32_t vertex(const I3& x) {
    bool inserted = false;
    const int32_t id = map_.find_or_insert(
        point_key(x), static_cast<int32_t>(lattice_.positions.size()), &inserted);
    if (inserted)
      lattice_.positions.push_back({origin_.x + unit_ * static_cast<double>(x[0]),
                                    origin_.y + unit_ * static_cast<double>(x[1]),
                                    origin_.z + unit_ * static_cast<double>(x[2])});
    return id;
  }

  void tet(int32_t a, int32_t b, int32_t c, int32_t d) {
    const auto& p = lattice_.positions;
    if (tet_signed_volume(p[a], p[b], p[c], p[d]) < 0) std::swap(c, d);
    lattice_.tets.push_back({a, b, c, d});
  }

  // Whether the cell edge along axis e, starting at corner `corner` (level coordinates), has a
  // vertex at its midpoint, i.e. one of the four cells around it is subdivided.
  bool edge_split(int level, const I3& corner, int e) const {
    const int p = (e + 1) % 3, q = (e + 2) % 3;
    for (int dp = -1; dp <= 0; ++dp)
      for (int dq = -1; dq <= 0; ++dq) {
        I3 x = corner;
        x[p] += dp;
        x[q] += dq;
        const Octree::Hit hit = tree_.find(level, x);
        if (hit.node >= 0 && hit.level == level && !tree_.is_leaf(hit.node)) return true;
      }
    return false;
  }

  void emit_cell(const Cell& c) {
    const int l = c.level;
    const int64_t u = int64_t{1} << (spec_.max_level - l + 1);  // cell size in key units
    const int64_t h = u / 2;
    const I3 base{c.index[0] * u, c.index[1] * u, c.index[2] * u};
    const int32_t centre = vertex({base[0] + h, base[1] + h, base[2] + h});

    // Edge splits, indexed [axis][offset along axis+1][offset along axis+2]; only a graded
    // lattice has them.
    bool split[3][2][2] = {};
    if (spec_.max_level > 0)
      for (int e = 0; e < 3; ++e)
        for (int o1 = 0; o1 < 2; ++o1)
          for (int o2 = 0; o2 < 2; ++o2) {
            I3 corner = c.index;
            corner[(e + 1) % 3] += o1;
            corner[(e + 2) % 3] += o2;
            split[e][o1][o2] = edge_split(l, corner, e);
          }

    for (int a = 0; a < 3; ++a)
      for (int side = 0; side < 2; ++side) {
        const int b = (a + 1) % 3, cc = (a + 2) % 3;
        I3 across = c.index;
        across[a] += side ? 1 : -1;
        const Octree::Hit hit = tree_.find(l, across);
        enum { kBoundary, kSmaller, kSame, kBigger } type;
        if (hit.node < 0) type = kBoundary;
        else if (hit.level < l) type = kSmaller;
        else if (tree_.is_leaf(hit.node)) type = kSame;
        else type = kBigger;  // the neighbour is subdivided: this face carries 4 sub-faces
        // A face between two equal leaves is emitted once, from its lower cell.
        if (type == kSame && side == 0) continue;

        const int64_t fa = base[a] + side * u;  // face plane
        auto point = [&](int64_t vb, int64_t vc) {
          I3 x;
          x[a] = fa;
          x[b] = vb;
          x[cc] = vc;
          return x;
        };

        if (type == kBigger) {
          // Four sub-squares, each fanned from its centre: matches the four smaller cells.
          const int64_t q = u / 4;
          for (int qb = 0; qb < 2; ++qb)
            for (int qc = 0; qc < 2; ++qc) {
              const int64_t b0 = base[b] + qb * h, c0 = base[cc] + qc * h;
              const int32_t s = vertex(point(b0 + q, c0 + q));
              const int32_t x[4] = {vertex(point(b0, c0)), vertex(point(b0 + h, c0)),
                                    vertex(point(b0 + h, c0 + h)), vertex(point(b0, c0 + h))};
              for (int k = 0; k < 4; ++k) tet(centre, s, x[k], x[(k + 1) % 4]);
            }
          continue;
        }

        // Second apex: the neighbour's centre (a whole BCC tetrahedron) or the face centre
        // (half of one).
        I3 apex_key;
        if (type == kSame) {
          apex_key = {base[0] + h, base[1] + h, base[2] + h};
          apex_key[a] += u;
        } else {
          apex_key = point(base[b] + h, base[cc] + h);
        }
        const int32_t apex = vertex(apex_key);
        const int oa = side;
        // The face's corners in cyclic order and whether each of its four edges is split.
        const int32_t corner[4] = {vertex(point(base[b], base[cc])),
                                   vertex(point(base[b] + u, base[cc])),
                                   vertex(point(base[b] + u, base[cc] + u)),
                                   vertex(point(base[b], base[cc] + u))};
        const bool edge_is_split[4] = {split[b][0][oa], split[cc][oa][1], split[b][1][oa],
                                       split[cc][oa][0]};
        const I3 mid[4] = {point(base[b] + h, base[cc]), point(base[b] + u, base[cc] + h),
                           point(base[b] + h, base[cc] + u), point(base[b], base[cc] + h)};
        for (int k = 0; k < 4; ++k) {
          const int32_t p0 = corner[k], p1 = corner[(k + 1) % 4];
          if (edge_is_split[k]) {
            const int32_t m = vertex(mid[k]);
            tet(centre, apex, p0, m);
            tet(centre, apex, m, p1);
          } else {
            tet(centre, apex, p0, p1);
          }
        }
      }
  }

  const LatticeSpec& spec_;
  Octree tree_;
  Vec3d origin_;
  double unit_;  // key unit [m]
  IndexMap map_;
  Lattice lattice_;
};

}  // namespace

Result<Lattice> build_lattice(const LatticeSpec& spec) {
  if (!(spec.coarse_size > 0) || spec.max_level < 0 || spec.max_level > 18 ||
      !(spec.z_offset >= 0 && spec.z_offset < 1))
    return make_error("mesh lattice: bad cell size %g m or depth %d", spec.coarse_size,
                      spec.max_level);
  // Root grid: symmetric about the origin, the origin on a cube corner, one spare cell beyond
  // the ellipsoid on each side so that the grid's own boundary faces lie outside it.
  I3 roots;
  Vec3d origin;
  for (int a = 0; a < 3; ++a) {
    const int64_t half = static_cast<int64_t>(std::ceil(spec.semi_axes[a] / spec.coarse_size)) + 1;
    roots[a] = 2 * half;
    origin[a] = -static_cast<double>(half) * spec.coarse_size;
    // A shift along z keeps the z axis on lattice lines (so a pole is always a mesh vertex)
    // while breaking the lattice's mirror symmetry about z = 0.
    if (a == 2) origin[a] += spec.z_offset * spec.coarse_size;
    if (roots[a] * (int64_t{2} << spec.max_level) >= kKeyLimit)
      return make_error(
          "mesh lattice: %lld root cells x 2^%d levels exceed the %d-bit lattice keys; use a "
          "larger edge length or a smaller coarse/fine ratio",
          static_cast<long long>(roots[a]), spec.max_level, kKeyBits);
  }
  LatticeBuilder builder(spec, roots, origin);
  builder.refine();
  builder.balance();
  return builder.emit();
}

}  // namespace zona::mesh_gen
