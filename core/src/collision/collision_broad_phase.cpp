// Broad phases for sphere-set collision: the seeds' AABB octree and a uniform spatial hash grid, plus the brute-force
// reference both must agree with.
#include "muscle_deformation/core/collision/collision_broad_phase.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numeric>
#include <stdexcept>

namespace muscle_deformation {

namespace {

// Boxes used only for pruning are grown by a hair so that rounding can never discard a pair the exact sphere test
// accepts (coordinates are metres: 1e-12 m is far above double rounding of body-sized scenes, far below any radius).
inline double paddedRadius(double r) { return r * (1.0 + 1e-9) + 1e-12; }

inline bool spheresOverlap(const Eigen::Matrix3Xd& ca, double ra, Eigen::Index i, const Eigen::Matrix3Xd& cb,
                           double rb, Eigen::Index j) {
  const double dx = ca(0, i) - cb(0, j);
  const double dy = ca(1, i) - cb(1, j);
  const double dz = ca(2, i) - cb(2, j);
  const double s = ra + rb;
  return dx * dx + dy * dy + dz * dz < s * s;
}

inline bool boxesOverlap(const Eigen::Vector3d& alo, const Eigen::Vector3d& ahi, const Eigen::Vector3d& blo,
                         const Eigen::Vector3d& bhi) {
  return alo.x() <= bhi.x() && blo.x() <= ahi.x() && alo.y() <= bhi.y() && blo.y() <= ahi.y() &&
         alo.z() <= bhi.z() && blo.z() <= ahi.z();
}

// ------------------------------------------------------------------------------------------------------------------
// AABB octree (thesis 4.3): one tree per object; a node is split into octants at its box midpoint only when a
// traversal first needs its children (lazy build); between iterations the existing nodes are refitted bottom-up.

class OctreeBroadPhase final : public BroadPhase {
 public:
  OctreeBroadPhase(int max_depth, int min_primitives) : max_depth_(max_depth), min_primitives_(min_primitives) {}

  BroadPhaseKind kind() const override { return BroadPhaseKind::octree; }

  void update(int id, const SphereSet& spheres, bool rebuild) override {
    if (id < 0) throw std::invalid_argument("OctreeBroadPhase::update: negative object id");
    if (static_cast<std::size_t>(id) >= trees_.size()) trees_.resize(static_cast<std::size_t>(id) + 1);
    Tree& tree = trees_[static_cast<std::size_t>(id)];
    const bool size_changed = tree.order.size() != static_cast<std::size_t>(spheres.size());
    tree.spheres = &spheres;
    if (rebuild || size_changed || tree.nodes.empty()) {
      tree.order.resize(static_cast<std::size_t>(spheres.size()));
      std::iota(tree.order.begin(), tree.order.end(), 0);
      tree.nodes.clear();
      Node root;
      root.first = 0;
      root.count = static_cast<std::int32_t>(spheres.size());
      tree.nodes.push_back(root);
    }
    tree.needs_refit = true;
  }

  void findPairs(int a, int b, std::vector<SpherePair>& pairs) override {
    pairs.clear();
    if (a == b) throw std::invalid_argument("OctreeBroadPhase::findPairs: an object does not collide with itself");
    Tree& ta = tree(a);
    Tree& tb = tree(b);
    if (ta.order.empty() || tb.order.empty()) return;
    refit(ta);
    refit(tb);
    traverse(ta, 0, tb, 0, pairs);
  }

 private:
  struct Node {
    Eigen::Vector3d lo = Eigen::Vector3d::Zero(), hi = Eigen::Vector3d::Zero();  // padded sphere bounds
    std::int32_t first = 0, count = 0;  // range in Tree::order
    std::int32_t first_child = -1;      // children are contiguous and stored after their parent
    std::int32_t child_count = 0;
    std::int32_t depth = 0;
    bool expanded = false;
  };
  struct Tree {
    const SphereSet* spheres = nullptr;
    std::vector<std::int32_t> order;  // sphere indices, grouped by node
    std::vector<Node> nodes;
    bool needs_refit = true;
  };

  Tree& tree(int id) {
    if (id < 0 || static_cast<std::size_t>(id) >= trees_.size() || trees_[static_cast<std::size_t>(id)].spheres == nullptr)
      throw std::invalid_argument("OctreeBroadPhase: object " + std::to_string(id) + " was never updated");
    return trees_[static_cast<std::size_t>(id)];
  }

  bool splittable(const Node& n) const { return n.depth < max_depth_ && n.count > min_primitives_; }

  static void fitPrimitives(const Tree& t, Node& n) {
    const SphereSet& s = *t.spheres;
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
    Eigen::Vector3d hi = -lo;
    for (std::int32_t k = n.first; k < n.first + n.count; ++k) {
      const std::int32_t i = t.order[static_cast<std::size_t>(k)];
      const double r = paddedRadius(s.radius[i]);
      lo = lo.cwiseMin((s.centre.col(i).array() - r).matrix());
      hi = hi.cwiseMax((s.centre.col(i).array() + r).matrix());
    }
    n.lo = lo;
    n.hi = hi;
  }

  // Children have larger indices than their parent, so a reverse sweep sees children before parents.
  static void refit(Tree& t) {
    if (!t.needs_refit) return;
    for (std::size_t k = t.nodes.size(); k-- > 0;) {
      Node& n = t.nodes[k];
      if (!n.expanded) {
        fitPrimitives(t, n);
      } else {
        n.lo = t.nodes[static_cast<std::size_t>(n.first_child)].lo;
        n.hi = t.nodes[static_cast<std::size_t>(n.first_child)].hi;
        for (std::int32_t c = 1; c < n.child_count; ++c) {
          const Node& child = t.nodes[static_cast<std::size_t>(n.first_child + c)];
          n.lo = n.lo.cwiseMin(child.lo);
          n.hi = n.hi.cwiseMax(child.hi);
        }
      }
    }
    t.needs_refit = false;
  }

  // Splits node `index` into up to eight children at its box midpoint (by sphere centre).
  void expand(Tree& t, std::int32_t index) {
    const SphereSet& s = *t.spheres;
    const Node parent = t.nodes[static_cast<std::size_t>(index)];
    const Eigen::Vector3d mid = 0.5 * (parent.lo + parent.hi);
    std::int32_t counts[8] = {0, 0, 0, 0, 0, 0, 0, 0};
    auto octant = [&](std::int32_t i) {
      return (s.centre(0, i) > mid.x() ? 1 : 0) | (s.centre(1, i) > mid.y() ? 2 : 0) | (s.centre(2, i) > mid.z() ? 4 : 0);
    };
    for (std::int32_t k = parent.first; k < parent.first + parent.count; ++k) ++counts[octant(t.order[static_cast<std::size_t>(k)])];
    std::int32_t start[8];
    std::int32_t running = parent.first;
    for (int o = 0; o < 8; ++o) {
      start[o] = running;
      running += counts[o];
    }
    scratch_.assign(t.order.begin() + parent.first, t.order.begin() + parent.first + parent.count);
    std::int32_t cursor[8];
    std::copy(start, start + 8, cursor);
    for (const std::int32_t i : scratch_) t.order[static_cast<std::size_t>(cursor[octant(i)]++)] = i;

    const auto first_child = static_cast<std::int32_t>(t.nodes.size());
    std::int32_t child_count = 0;
    for (int o = 0; o < 8; ++o) {
      if (counts[o] == 0) continue;
      Node child;
      child.first = start[o];
      child.count = counts[o];
      child.depth = parent.depth + 1;
      fitPrimitives(t, child);
      t.nodes.push_back(child);
      ++child_count;
    }
    Node& p = t.nodes[static_cast<std::size_t>(index)];  // re-fetch: push_back may have moved the array
    p.first_child = first_child;
    p.child_count = child_count;
    p.expanded = true;
  }

  void leafPairs(const Tree& ta, const Node& na, const Tree& tb, const Node& nb, std::vector<SpherePair>& pairs) const {
    const SphereSet& sa = *ta.spheres;
    const SphereSet& sb = *tb.spheres;
    for (std::int32_t ka = na.first; ka < na.first + na.count; ++ka) {
      const std::int32_t i = ta.order[static_cast<std::size_t>(ka)];
      const double ri = sa.radius[i];
      const double rpad = paddedRadius(ri);
      // One sphere against the other node's box first: most spheres of a leaf are far from the other leaf.
      const Eigen::Vector3d lo = sa.centre.col(i).array() - rpad;
      const Eigen::Vector3d hi = sa.centre.col(i).array() + rpad;
      if (!boxesOverlap(lo, hi, nb.lo, nb.hi)) continue;
      for (std::int32_t kb = nb.first; kb < nb.first + nb.count; ++kb) {
        const std::int32_t j = tb.order[static_cast<std::size_t>(kb)];
        if (spheresOverlap(sa.centre, ri, i, sb.centre, sb.radius[j], j)) pairs.push_back({i, j});
      }
    }
  }

  // The seeds' pairwise traversal: on overlap, descend both nodes (or the one that can still be split); test
  // primitives when neither can.
  void traverse(Tree& ta, std::int32_t ia, Tree& tb, std::int32_t ib, std::vector<SpherePair>& pairs) {
    {
      const Node& na = ta.nodes[static_cast<std::size_t>(ia)];
      const Node& nb = tb.nodes[static_cast<std::size_t>(ib)];
      if (!boxesOverlap(na.lo, na.hi, nb.lo, nb.hi)) return;
    }
    const bool split_a = splittable(ta.nodes[static_cast<std::size_t>(ia)]);
    const bool split_b = splittable(tb.nodes[static_cast<std::size_t>(ib)]);
    if (!split_a && !split_b) {
      leafPairs(ta, ta.nodes[static_cast<std::size_t>(ia)], tb, tb.nodes[static_cast<std::size_t>(ib)], pairs);
      return;
    }
    if (split_a && !ta.nodes[static_cast<std::size_t>(ia)].expanded) expand(ta, ia);
    if (split_b && !tb.nodes[static_cast<std::size_t>(ib)].expanded) expand(tb, ib);
    // Copy the child ranges: recursion may grow the node arrays and invalidate references.
    const std::int32_t a0 = split_a ? ta.nodes[static_cast<std::size_t>(ia)].first_child : ia;
    const std::int32_t an = split_a ? ta.nodes[static_cast<std::size_t>(ia)].child_count : 1;
    const std::int32_t b0 = split_b ? tb.nodes[static_cast<std::size_t>(ib)].first_child : ib;
    const std::int32_t bn = split_b ? tb.nodes[static_cast<std::size_t>(ib)].child_count : 1;
    for (std::int32_t ca = a0; ca < a0 + an; ++ca)
      for (std::int32_t cb = b0; cb < b0 + bn; ++cb) traverse(ta, ca, tb, cb, pairs);
  }

  int max_depth_;
  int min_primitives_;
  std::vector<Tree> trees_;
  std::vector<std::int32_t> scratch_;
};

// ------------------------------------------------------------------------------------------------------------------
// Uniform spatial hash grid (Teschner et al. 2003): space is cut into cubic cells of edge h; every sphere is entered
// in each cell its box touches, and cells are stored in a fixed-size table by hashing their integer coordinates.
// A query sphere looks into the cells its box touches and keeps a candidate only in the one cell holding the lower
// corner of the two boxes' intersection, so every pair is reported exactly once without a de-duplication pass.
// Two uses: one grid per object, rebuilt lazily after it moved (bones: once per pose), queried by another object's
// spheres; and one grid over a whole group of objects (all muscles), rebuilt every iteration and queried by its own
// spheres, which finds all muscle-muscle pairs in one pass.

class HashGridBroadPhase final : public BroadPhase {
 public:
  explicit HashGridBroadPhase(double cell_scale) : cell_scale_(cell_scale) {}

  BroadPhaseKind kind() const override { return BroadPhaseKind::hash_grid; }

  void update(int id, const SphereSet& spheres, bool /*rebuild*/) override {
    if (id < 0) throw std::invalid_argument("HashGridBroadPhase::update: negative object id");
    if (static_cast<std::size_t>(id) >= objects_.size()) objects_.resize(static_cast<std::size_t>(id) + 1);
    Object& o = objects_[static_cast<std::size_t>(id)];
    o.spheres = &spheres;
    o.grid.needs_build = true;
  }

  void findPairs(int a, int b, std::vector<SpherePair>& pairs) override {
    pairs.clear();
    if (a == b) throw std::invalid_argument("HashGridBroadPhase::findPairs: an object does not collide with itself");
    Object& oa = object(a);
    Object& ob = object(b);
    if (oa.spheres->size() == 0 || ob.spheres->size() == 0) return;
    // Hash the larger set, query with the smaller: query cost grows with the query count, and a grid once built
    // serves every other object until its owner moves (bones: until the next pose).
    const bool hash_a = oa.spheres->size() >= ob.spheres->size();
    Object& hashed = hash_a ? oa : ob;
    const SphereSet& q = hash_a ? *ob.spheres : *oa.spheres;
    if (hashed.grid.needs_build) {
      single_set_[0] = hashed.spheres;
      build(hashed.grid, single_set_);
    }
    const Grid& g = hashed.grid;
    for (Eigen::Index j = 0; j < q.size(); ++j) {
      const auto jj = static_cast<std::int32_t>(j);
      queryOne(g, q, j, [&](std::int32_t /*set*/, std::int32_t i) {
        pairs.push_back(hash_a ? SpherePair{i, jj} : SpherePair{jj, i});
      });
    }
  }

  void findPairsAmong(const std::vector<int>& ids, const std::vector<std::uint8_t>& test_pair,
                      std::vector<ObjectSpherePair>& pairs) override {
    pairs.clear();
    const std::size_t n = ids.size();
    if (test_pair.size() != n * n) throw std::invalid_argument("HashGridBroadPhase::findPairsAmong: test_pair size");
    // Only objects that take part in at least one tested pair go into the group grid.
    group_sets_.clear();
    group_ids_.clear();
    for (std::size_t i = 0; i < n; ++i) {
      bool used = false;
      for (std::size_t j = 0; j < n && !used; ++j) used = i != j && test_pair[i < j ? i * n + j : j * n + i];
      if (!used || object(ids[i]).spheres->size() == 0) continue;
      group_sets_.push_back(object(ids[i]).spheres);
      group_ids_.push_back(static_cast<std::int32_t>(i));
    }
    if (group_sets_.size() < 2) return;
    build(group_grid_, group_sets_);
    // Every overlapping pair shares at least one cell (the one holding the lower corner of the boxes' intersection),
    // so scanning each bucket's entries pairwise finds them all; the corner rule keeps one cell per pair. Buckets
    // are contiguous, so this pass reads memory in order instead of looking cells up.
    const Grid& g = group_grid_;
    for (std::size_t h = 0; h + 1 < g.bucket_start.size(); ++h) {
      const std::uint32_t begin = g.bucket_start[h], end = g.bucket_start[h + 1];
      for (std::uint32_t k = begin; k + 1 < end; ++k) {
        const Entry& e1 = g.entries[k];
        const Eigen::Index g1 = g.first[static_cast<std::size_t>(e1.set)] + e1.sphere;
        for (std::uint32_t l = k + 1; l < end; ++l) {
          const Entry& e2 = g.entries[l];
          if (e1.set == e2.set || e1.x != e2.x || e1.y != e2.y || e1.z != e2.z) continue;
          const std::size_t i1 = static_cast<std::size_t>(group_ids_[static_cast<std::size_t>(e1.set)]);
          const std::size_t i2 = static_cast<std::size_t>(group_ids_[static_cast<std::size_t>(e2.set)]);
          if (!test_pair[i1 < i2 ? i1 * n + i2 : i2 * n + i1]) continue;
          const Eigen::Index g2 = g.first[static_cast<std::size_t>(e2.set)] + e2.sphere;
          const double dx = g.sphere(0, g1) - g.sphere(0, g2), dy = g.sphere(1, g1) - g.sphere(1, g2),
                       dz = g.sphere(2, g1) - g.sphere(2, g2), reach = g.sphere(3, g1) + g.sphere(3, g2);
          if (!(dx * dx + dy * dy + dz * dz < reach * reach)) continue;
          if (cellOf(std::max(g.sphere_lo(0, g1), g.sphere_lo(0, g2)), g.inv_cell) != e1.x ||
              cellOf(std::max(g.sphere_lo(1, g1), g.sphere_lo(1, g2)), g.inv_cell) != e1.y ||
              cellOf(std::max(g.sphere_lo(2, g1), g.sphere_lo(2, g2)), g.inv_cell) != e1.z)
            continue;
          if (ids[i1] < ids[i2])
            pairs.push_back({ids[i1], ids[i2], e1.sphere, e2.sphere});
          else
            pairs.push_back({ids[i2], ids[i1], e2.sphere, e1.sphere});
        }
      }
    }
  }

 private:
  struct Entry {
    std::int32_t set;      // which sphere set of the grid
    std::int32_t sphere;   // index within that set
    std::int32_t x, y, z;  // cell coordinates, to skip entries of other cells sharing the bucket
  };
  struct Grid {
    bool needs_build = true;
    std::vector<const SphereSet*> sets;
    std::vector<std::int32_t> first;  // offset of each set in the per-sphere arrays
    double inv_cell = 1.0;
    Eigen::Vector3d lo = Eigen::Vector3d::Zero(), hi = Eigen::Vector3d::Zero();  // padded bounds of all spheres
    Eigen::Matrix3Xd sphere_lo = Eigen::Matrix3Xd(3, 0);  // padded box corners of each sphere, all sets
    Eigen::Matrix3Xd sphere_hi = Eigen::Matrix3Xd(3, 0);
    Eigen::Matrix4Xd sphere = Eigen::Matrix4Xd(4, 0);  // centre and radius of each sphere, all sets, contiguous
    std::uint32_t mask = 0;
    std::vector<std::uint32_t> bucket_start;  // size mask + 2: entries of bucket k are [start[k], start[k+1])
    std::vector<Entry> entries;
  };
  struct Object {
    const SphereSet* spheres = nullptr;
    Grid grid;
  };

  Object& object(int id) {
    if (id < 0 || static_cast<std::size_t>(id) >= objects_.size() || objects_[static_cast<std::size_t>(id)].spheres == nullptr)
      throw std::invalid_argument("HashGridBroadPhase: object " + std::to_string(id) + " was never updated");
    return objects_[static_cast<std::size_t>(id)];
  }

  static std::int32_t cellOf(double x, double inv_cell) { return static_cast<std::int32_t>(std::floor(x * inv_cell)); }

  static std::uint32_t hashOf(std::int32_t x, std::int32_t y, std::int32_t z, std::uint32_t mask) {
    // Teschner et al.'s large primes, then a Fibonacci multiply whose high bits index the table: the primes alone
    // leave the low bits (all a power-of-two table would use) depending only on the coordinates' low bits, which
    // piled a body-sized scene into a few long buckets.
    const std::uint64_t h = (static_cast<std::uint64_t>(static_cast<std::uint32_t>(x)) * 73856093u) ^
                            (static_cast<std::uint64_t>(static_cast<std::uint32_t>(y)) * 19349663u) ^
                            (static_cast<std::uint64_t>(static_cast<std::uint32_t>(z)) * 83492791u);
    return static_cast<std::uint32_t>((h * 0x9E3779B97F4A7C15ull) >> 32) & mask;
  }

  template <class Visit>
  static void forEachCell(double inv_cell, const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, Visit visit) {
    const std::int32_t x0 = cellOf(lo.x(), inv_cell), x1 = cellOf(hi.x(), inv_cell);
    const std::int32_t y0 = cellOf(lo.y(), inv_cell), y1 = cellOf(hi.y(), inv_cell);
    const std::int32_t z0 = cellOf(lo.z(), inv_cell), z1 = cellOf(hi.z(), inv_cell);
    for (std::int32_t x = x0; x <= x1; ++x)
      for (std::int32_t y = y0; y <= y1; ++y)
        for (std::int32_t z = z0; z <= z1; ++z) visit(x, y, z);
  }

  void build(Grid& g, const std::vector<const SphereSet*>& sets) {
    g.sets = sets;
    g.first.resize(sets.size() + 1);
    Eigen::Index n = 0;
    double radius_sum = 0, radius_max = 0;
    for (std::size_t s = 0; s < sets.size(); ++s) {
      g.first[s] = static_cast<std::int32_t>(n);
      n += sets[s]->size();
      if (sets[s]->size() > 0) {
        radius_sum += sets[s]->radius.sum();
        radius_max = std::max(radius_max, sets[s]->radius.maxCoeff());
      }
    }
    g.first[sets.size()] = static_cast<std::int32_t>(n);
    // Cell edge: Teschner et al. found about one primitive size best. Large spheres are capped at 8 cells a side so
    // a few big ones cannot flood the table.
    const double mean_diameter = n > 0 ? 2.0 * radius_sum / static_cast<double>(n) : 0.0;
    double cell = std::max(cell_scale_ * mean_diameter, 2.0 * radius_max / 8.0);
    if (!(cell > 0.0)) cell = 1e-3;  // all radii zero: nothing can overlap, any cell works
    g.inv_cell = 1.0 / cell;

    g.sphere_lo.resize(3, n);
    g.sphere_hi.resize(3, n);
    g.sphere.resize(4, n);
    g.lo.setConstant(std::numeric_limits<double>::infinity());
    g.hi = -g.lo;
    std::size_t total = 0;
    for (std::size_t s = 0; s < sets.size(); ++s) {
      const SphereSet& set = *sets[s];
      for (Eigen::Index i = 0; i < set.size(); ++i) {
        const Eigen::Index k = g.first[s] + i;
        const double r = paddedRadius(set.radius[i]);
        g.sphere_lo.col(k) = set.centre.col(i).array() - r;
        g.sphere_hi.col(k) = set.centre.col(i).array() + r;
        g.sphere.col(k) << set.centre.col(i), set.radius[i];
        g.lo = g.lo.cwiseMin(g.sphere_lo.col(k));
        g.hi = g.hi.cwiseMax(g.sphere_hi.col(k));
        std::size_t cells = 1;
        for (int d = 0; d < 3; ++d)
          cells *= static_cast<std::size_t>(cellOf(g.sphere_hi(d, k), g.inv_cell) - cellOf(g.sphere_lo(d, k), g.inv_cell) + 1);
        total += cells;
      }
    }
    // Table about twice the entries (power of two so the modulo is a mask); never shrunk, so no reallocation.
    std::size_t table = 1;
    while (table < 2 * total) table <<= 1;
    if (table > static_cast<std::size_t>(g.mask) + 1 || g.bucket_start.empty()) g.mask = static_cast<std::uint32_t>(table - 1);
    g.bucket_start.assign(static_cast<std::size_t>(g.mask) + 2, 0u);
    for (Eigen::Index k = 0; k < n; ++k)
      forEachCell(g.inv_cell, g.sphere_lo.col(k), g.sphere_hi.col(k), [&](std::int32_t x, std::int32_t y, std::int32_t z) {
        ++g.bucket_start[hashOf(x, y, z, g.mask) + 1];
      });
    for (std::size_t k = 1; k < g.bucket_start.size(); ++k) g.bucket_start[k] += g.bucket_start[k - 1];
    g.entries.resize(total);
    // Fill with a cursor per bucket; the cursors are the starts shifted by one, restored afterwards.
    for (std::size_t s = 0; s < sets.size(); ++s)
      for (Eigen::Index i = 0; i < sets[s]->size(); ++i) {
        const Eigen::Index k = g.first[s] + i;
        forEachCell(g.inv_cell, g.sphere_lo.col(k), g.sphere_hi.col(k), [&](std::int32_t x, std::int32_t y, std::int32_t z) {
          const std::uint32_t h = hashOf(x, y, z, g.mask);
          g.entries[g.bucket_start[h]++] = Entry{static_cast<std::int32_t>(s), static_cast<std::int32_t>(i), x, y, z};
        });
      }
    for (std::size_t k = g.bucket_start.size() - 1; k > 0; --k) g.bucket_start[k] = g.bucket_start[k - 1];
    g.bucket_start[0] = 0;
    g.needs_build = false;
  }

  // Calls found(set, sphere) for every sphere of grid `g` overlapping sphere j of `q`, each exactly once.
  template <class Found>
  static void queryOne(const Grid& g, const SphereSet& q, Eigen::Index j, Found found) {
    const double rj = q.radius[j];
    const double rpad = paddedRadius(rj);
    const Eigen::Vector3d qlo = q.centre.col(j).array() - rpad;
    const Eigen::Vector3d qhi = q.centre.col(j).array() + rpad;
    if (!boxesOverlap(qlo, qhi, g.lo, g.hi)) return;
    // Only the part of the query box inside the grid's bounds can meet anything.
    const Eigen::Vector3d lo = qlo.cwiseMax(g.lo), hi = qhi.cwiseMin(g.hi);
    forEachCell(g.inv_cell, lo, hi, [&](std::int32_t x, std::int32_t y, std::int32_t z) {
      const std::uint32_t h = hashOf(x, y, z, g.mask);
      for (std::uint32_t k = g.bucket_start[h]; k < g.bucket_start[h + 1]; ++k) {
        const Entry& e = g.entries[k];
        if (e.x != x || e.y != y || e.z != z) continue;
        const SphereSet& s = *g.sets[static_cast<std::size_t>(e.set)];
        if (!spheresOverlap(s.centre, s.radius[e.sphere], e.sphere, q.centre, rj, j)) continue;
        // Report in the cell of the lower corner of the two boxes' intersection only.
        const Eigen::Index gi = g.first[static_cast<std::size_t>(e.set)] + e.sphere;
        if (cellOf(std::max(g.sphere_lo(0, gi), qlo.x()), g.inv_cell) != x ||
            cellOf(std::max(g.sphere_lo(1, gi), qlo.y()), g.inv_cell) != y ||
            cellOf(std::max(g.sphere_lo(2, gi), qlo.z()), g.inv_cell) != z)
          continue;
        found(e.set, e.sphere);
      }
    });
  }

  double cell_scale_;
  std::vector<Object> objects_;
  std::vector<const SphereSet*> single_set_ = std::vector<const SphereSet*>(1, nullptr);
  Grid group_grid_;
  std::vector<const SphereSet*> group_sets_;
  std::vector<std::int32_t> group_ids_;  // index into `ids` of each group set
};

}  // namespace

AlignedBox sphereBounds(const SphereSet& spheres) {
  AlignedBox box;
  for (Eigen::Index i = 0; i < spheres.size(); ++i) {
    box.extend(spheres.centre.col(i).array() - spheres.radius[i]);
    box.extend(spheres.centre.col(i).array() + spheres.radius[i]);
  }
  return box;
}

void overlappingPairsBruteForce(const SphereSet& a, const SphereSet& b, std::vector<SpherePair>& pairs) {
  pairs.clear();
  for (Eigen::Index i = 0; i < a.size(); ++i)
    for (Eigen::Index j = 0; j < b.size(); ++j)
      if (spheresOverlap(a.centre, a.radius[i], i, b.centre, b.radius[j], j))
        pairs.push_back({static_cast<std::int32_t>(i), static_cast<std::int32_t>(j)});
}

void BroadPhase::findPairsAmong(const std::vector<int>& ids, const std::vector<std::uint8_t>& test_pair,
                                std::vector<ObjectSpherePair>& pairs) {
  pairs.clear();
  const std::size_t n = ids.size();
  if (test_pair.size() != n * n) throw std::invalid_argument("BroadPhase::findPairsAmong: test_pair size");
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t j = i + 1; j < n; ++j) {
      if (!test_pair[i * n + j]) continue;
      const bool i_first = ids[i] < ids[j];
      findPairs(i_first ? ids[i] : ids[j], i_first ? ids[j] : ids[i], scratch_pairs_);
      const std::int32_t a = i_first ? ids[i] : ids[j], b = i_first ? ids[j] : ids[i];
      for (const SpherePair& p : scratch_pairs_) pairs.push_back({a, b, p.first, p.second});
    }
}

std::unique_ptr<BroadPhase> makeBroadPhase(const CollisionSettings& settings) {
  const std::string problem = validate(settings);
  if (!problem.empty()) throw std::invalid_argument("CollisionSettings: " + problem);
  switch (settings.broad_phase) {
    case BroadPhaseKind::octree:
      return std::make_unique<OctreeBroadPhase>(settings.octree_max_depth, settings.octree_min_primitives);
    case BroadPhaseKind::hash_grid:
      return std::make_unique<HashGridBroadPhase>(settings.hash_cell_scale);
  }
  throw std::invalid_argument("CollisionSettings: unknown broad phase");
}

}  // namespace muscle_deformation
