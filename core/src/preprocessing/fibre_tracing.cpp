// Fibre generation, the tracing step: geometry helpers, seeds, streamlines, resampling, tracing from a cross-section.
#include "fibre_tracing.hpp"

#include <algorithm>
#include <cmath>
#include <utility>

namespace muscle_deformation::fibre_steps {

// ---------------------------------------------------------------------------------------------------------------
// Geometry helpers

namespace {

double segmentSegmentDistance(const Eigen::Vector3d& p1, const Eigen::Vector3d& q1, const Eigen::Vector3d& p2,
                              const Eigen::Vector3d& q2) {
  const Eigen::Vector3d d1 = q1 - p1, d2 = q2 - p2, r = p1 - p2;
  const double a = d1.squaredNorm(), e = d2.squaredNorm(), f = d2.dot(r);
  double s = 0, t = 0;
  if (a <= 1e-30 && e <= 1e-30) return r.norm();
  if (a <= 1e-30) {
    t = std::clamp(f / e, 0.0, 1.0);
  } else {
    const double c = d1.dot(r);
    if (e <= 1e-30) {
      s = std::clamp(-c / a, 0.0, 1.0);
    } else {
      const double b = d1.dot(d2), denom = a * e - b * b;
      s = denom > 1e-30 ? std::clamp((b * f - c * e) / denom, 0.0, 1.0) : 0.0;
      t = (b * s + f) / e;
      if (t < 0) {
        t = 0;
        s = std::clamp(-c / a, 0.0, 1.0);
      } else if (t > 1) {
        t = 1;
        s = std::clamp((b - c) / a, 0.0, 1.0);
      }
    }
  }
  return ((p1 + s * d1) - (p2 + t * d2)).norm();
}

}  // namespace

double pointSegmentDistance(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  const Eigen::Vector3d ab = b - a;
  const double len2 = ab.squaredNorm();
  const double t = len2 > 0 ? std::clamp((p - a).dot(ab) / len2, 0.0, 1.0) : 0.0;
  return (a + t * ab - p).norm();
}

// Closest approach of two polylines (segment to segment), skipping the work when their boxes are farther apart than
// `bound` (then returns bound).
double polylineDistance(const Polyline& a, const Polyline& b, const AlignedBox& box_a, const AlignedBox& box_b,
                        double bound) {
  const Eigen::Vector3d gap =
      (box_a.min - box_b.max).cwiseMax(box_b.min - box_a.max).cwiseMax(Eigen::Vector3d::Zero());
  if (gap.norm() >= bound) return bound;
  double best = bound;
  for (Eigen::Index i = 0; i + 1 < a.cols(); ++i)
    for (Eigen::Index j = 0; j + 1 < b.cols(); ++j)
      best = std::min(best, segmentSegmentDistance(a.col(i), a.col(i + 1), b.col(j), b.col(j + 1)));
  return best;
}

// The surface triangles touching a patch (any corner in it).
TriangleMesh patchSurface(const TriangleMesh& surface, const std::vector<int>& vertices) {
  std::vector<char> in(static_cast<std::size_t>(surface.vertexCount()), 0);
  for (int v : vertices) in[static_cast<std::size_t>(v)] = 1;
  std::vector<Eigen::Index> keep;
  for (Eigen::Index t = 0; t < surface.triangleCount(); ++t)
    if (in[surface.triangles(0, t)] || in[surface.triangles(1, t)] || in[surface.triangles(2, t)]) keep.push_back(t);
  TriangleMesh out;
  out.vertices = surface.vertices;
  out.triangles.resize(3, static_cast<Eigen::Index>(keep.size()));
  for (std::size_t i = 0; i < keep.size(); ++i) out.triangles.col(static_cast<Eigen::Index>(i)) = surface.triangles.col(keep[i]);
  return out;
}

namespace {

// Where the ray from `from` through `to` first leaves `surface`, within `reach` beyond `to` (Moller-Trumbore);
// false if it does not.
bool rayExit(const TriangleMesh& surface, const Eigen::Vector3d& from, const Eigen::Vector3d& to, double reach,
             Eigen::Vector3d& hit) {
  const Eigen::Vector3d d = (to - from).normalized();
  if (!d.allFinite()) return false;
  double best = kInf;
  for (Eigen::Index t = 0; t < surface.triangleCount(); ++t) {
    const Eigen::Vector3d a = surface.vertices.col(surface.triangles(0, t));
    const Eigen::Vector3d e1 = surface.vertices.col(surface.triangles(1, t)) - a;
    const Eigen::Vector3d e2 = surface.vertices.col(surface.triangles(2, t)) - a;
    const Eigen::Vector3d q = d.cross(e2);
    const double det = e1.dot(q);
    if (std::abs(det) < 1e-18) continue;
    const Eigen::Vector3d r = to - a;
    const double u = r.dot(q) / det;
    if (u < 0 || u > 1) continue;
    const Eigen::Vector3d w = r.cross(e1);
    const double v = d.dot(w) / det;
    if (v < 0 || u + v > 1) continue;
    const double dist = e2.dot(w) / det;
    if (dist >= 0 && dist <= reach && dist < best) best = dist;
  }
  if (!std::isfinite(best)) return false;
  hit = to + best * d;
  return true;
}

Polyline resample(const std::vector<Eigen::Vector3d>& points, int count) {
  std::vector<double> s(points.size(), 0.0);
  for (std::size_t i = 1; i < points.size(); ++i) s[i] = s[i - 1] + (points[i] - points[i - 1]).norm();
  Polyline out(3, count);
  std::size_t seg = 1;
  for (int k = 0; k < count; ++k) {
    const double target = s.back() * k / (count - 1);
    while (seg + 1 < points.size() && s[seg] < target) ++seg;
    const double span = s[seg] - s[seg - 1];
    const double t = span > 0 ? std::clamp((target - s[seg - 1]) / span, 0.0, 1.0) : 0.0;
    out.col(k) = (1 - t) * points[seg - 1] + t * points[seg];
  }
  out.col(0) = points.front();
  out.col(count - 1) = points.back();
  return out;
}

// ---------------------------------------------------------------------------------------------------------------
// Seeds and streamlines

// `count` well-spread samples of the cross-section: farthest-point sampling, then Lloyd iterations (each seed moves to
// the area-weighted centroid of the samples nearest to it, snapped back onto a sample), which evens out the spacing
// and keeps seeds half a spacing away from the rim.
std::vector<std::size_t> spreadSeeds(const CrossSection& section, const std::vector<char>& allowed, int count) {
  std::vector<std::size_t> candidates;
  for (std::size_t i = 0; i < section.points.size(); ++i)
    if (allowed[i]) candidates.push_back(i);
  if (candidates.size() <= static_cast<std::size_t>(count)) return candidates;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  double total = 0;
  for (std::size_t i : candidates) {
    centroid += section.areas[i] * section.points[i];
    total += section.areas[i];
  }
  centroid /= total;
  std::vector<double> nearest(candidates.size(), kInf);
  std::vector<std::size_t> seeds;
  std::size_t pick = 0;
  double best = kInf;
  for (std::size_t c = 0; c < candidates.size(); ++c) {
    const double d = (section.points[candidates[c]] - centroid).squaredNorm();
    if (d < best) {
      best = d;
      pick = c;
    }
  }
  for (int s = 0; s < count; ++s) {
    seeds.push_back(candidates[pick]);
    const Eigen::Vector3d& p = section.points[candidates[pick]];
    double farthest = -1;
    for (std::size_t c = 0; c < candidates.size(); ++c) {
      nearest[c] = std::min(nearest[c], (section.points[candidates[c]] - p).squaredNorm());
      if (nearest[c] > farthest) {
        farthest = nearest[c];
        pick = c;
      }
    }
  }
  std::vector<int> owner(candidates.size(), 0);
  for (int iteration = 0; iteration < 40; ++iteration) {
    for (std::size_t c = 0; c < candidates.size(); ++c) {
      double d_best = kInf;
      for (int s = 0; s < count; ++s) {
        const double d = (section.points[candidates[c]] - section.points[seeds[static_cast<std::size_t>(s)]]).squaredNorm();
        if (d < d_best) {
          d_best = d;
          owner[c] = s;
        }
      }
    }
    std::vector<Eigen::Vector3d> sums(static_cast<std::size_t>(count), Eigen::Vector3d::Zero());
    std::vector<double> weights(static_cast<std::size_t>(count), 0.0);
    for (std::size_t c = 0; c < candidates.size(); ++c) {
      sums[static_cast<std::size_t>(owner[c])] += section.areas[candidates[c]] * section.points[candidates[c]];
      weights[static_cast<std::size_t>(owner[c])] += section.areas[candidates[c]];
    }
    std::vector<double> snap(static_cast<std::size_t>(count), kInf);
    std::vector<std::size_t> moved = seeds;
    for (std::size_t c = 0; c < candidates.size(); ++c) {
      const std::size_t s = static_cast<std::size_t>(owner[c]);
      if (!(weights[s] > 0)) continue;
      const double d = (section.points[candidates[c]] - sums[s] / weights[s]).squaredNorm();
      if (d < snap[s]) {
        snap[s] = d;
        moved[s] = candidates[c];
      }
    }
    if (moved == seeds) break;
    seeds.swap(moved);
  }
  return seeds;
}

// Follows the normalised gradient (direction +1 towards the insertion, -1 towards the origin) with RK4 until the
// nearest voxel is a Dirichlet voxel of `target`. Appends the points after `start`; false if it left the muscle or
// stalled first.
bool traceStreamline(const Field& f, const Eigen::Vector3d& start, double direction, int target,
                     const SurfaceDistance& target_patch, double step, int max_steps,
                     std::vector<Eigen::Vector3d>& out) {
  // Stop a voxel and a half short of the patch: in the last voxels streamlines funnelled into a small patch run along
  // the staircase rim and would be squeezed together; the fibre is finished with a straight segment instead.
  const double arrive = 1.5 * f.grid.h;
  auto heading = [&](const Eigen::Vector3d& p, Eigen::Vector3d& d) {
    Eigen::Vector3d g;
    if (!f.sample(p, nullptr, &g)) return false;
    const double norm = g.norm();
    if (!(norm > 1e-9)) return false;
    d = direction * g / norm;
    return true;
  };
  Eigen::Vector3d p = start;
  double value = 0;
  f.sample(p, &value, nullptr);
  int regressions = 0;
  for (int s = 0; s < max_steps; ++s) {
    if (target_patch.distanceWithin(p, arrive) <= arrive) return true;
    // In a Dirichlet voxel labelled through a coarse patch vertex, but not near the patch itself: the field is flat
    // here, so the streamline cannot reach the patch (it is reseeded).
    if (f.labelAt(p) == target) return target_patch.distanceWithin(p, 2 * f.grid.h) <= 2 * f.grid.h;
    Eigen::Vector3d k1, k2, k3, k4;
    if (!heading(p, k1)) return false;
    Eigen::Vector3d next;
    if (heading(p + 0.5 * step * k1, k2) && heading(p + 0.5 * step * k2, k3) && heading(p + step * k3, k4)) {
      next = p + step / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4);
    } else {
      next = p + step * k1;  // at the rim the RK4 stages may fall off the grid: an Euler step still moves on
    }
    if (!f.inDomain(next) && !f.pullInside(next)) return false;
    double next_value = value;
    if (!f.sample(next, &next_value, nullptr)) return false;
    // The field must keep rising (or falling): several steps against it mean a stagnation point.
    // Likewise a step that the rim pull undid: the streamline is pinned in a corner of the staircase, where it would
    // converge onto the same point as its neighbours.
    if ((next_value - value) * direction <= 0 || (next - p).norm() < 0.25 * step) {
      if (++regressions > 5) return false;
    }
    value = next_value;
    p = next;
    out.push_back(p);
  }
  return false;
}

}  // namespace

StreamlineTracer::StreamlineTracer(const Field& field, const TriangleMesh& surface, const AttachmentPatches& patches,
                                   const FibreGeneratorOptions& options)
    : field_(field),
      surface_(surface),
      options_(options),
      h_(field.grid.h),
      step_(options.step_voxels * field.grid.h),
      origin_surface_(patchSurface(surface, patches.origin_vertices)),
      insertion_surface_(patchSurface(surface, patches.insertion_vertices)),
      origin_distance_(origin_surface_.vertices, origin_surface_.triangles),
      insertion_distance_(insertion_surface_.vertices, insertion_surface_.triangles) {
  const AlignedBox box = boundsOf(surface.vertices);
  max_steps_ = static_cast<int>(4.0 * (box.max - box.min).norm() / step_) + 10;
}

TracedFibres StreamlineTracer::traceFrom(const CrossSection& section) const {
  TracedFibres out;
  std::vector<char> allowed(section.points.size(), 1);
  const double spacing = std::sqrt(section.area / (M_PI * options_.fibre_count));
  for (int round = 0; round < 6; ++round) {
    const std::vector<std::size_t> seeds = spreadSeeds(section, allowed, options_.fibre_count);
    std::vector<Polyline> fibres;
    std::vector<std::size_t> failed, traced_seeds;
    for (std::size_t seed : seeds) {
      Polyline fibre;
      if (!traceFibre(section.points[seed], fibre)) {
        failed.push_back(seed);
        continue;
      }
      fibres.push_back(std::move(fibre));
      traced_seeds.push_back(seed);
    }
    // Streamlines funnelled into a narrow tendon can come within micrometres of each other (and would coincide once
    // written with finite precision): keep the first of such a pair, reseed near the other.
    const double min_separation = options_.min_separation;
    std::vector<AlignedBox> boxes;
    for (const Polyline& fibre : fibres) boxes.push_back(boundsOf(fibre));
    std::vector<char> drop(fibres.size(), 0);
    for (std::size_t a = 0; a < fibres.size(); ++a)
      for (std::size_t b = a + 1; b < fibres.size(); ++b)
        if (!drop[a] && !drop[b] &&
            polylineDistance(fibres[a], fibres[b], boxes[a], boxes[b], min_separation) < min_separation) {
          drop[b] = 1;
        }
    std::vector<Polyline> kept;
    int merged = 0;
    for (std::size_t i = 0; i < fibres.size(); ++i) {
      if (drop[i]) {
        failed.push_back(traced_seeds[i]);
        ++merged;
      } else {
        kept.push_back(std::move(fibres[i]));
      }
    }
    fibres.swap(kept);
    if (failed.empty() || round == 5) {  // the last round's losses are not reseeded: the count shows them
      out.fibres = std::move(fibres);
      break;
    }
    out.failed_seeds += static_cast<int>(failed.size());
    out.merged_fibres += merged;
    ++out.reseed_rounds;
    for (std::size_t s = 0; s < section.points.size(); ++s)
      for (std::size_t f : failed)
        if ((section.points[s] - section.points[f]).norm() < 0.5 * spacing) allowed[s] = 0;
  }
  return out;
}

bool StreamlineTracer::traceFibre(const Eigen::Vector3d& start, Polyline& fibre) const {
  std::vector<Eigen::Vector3d> back, forward;
  if (!traceStreamline(field_, start, -1.0, 0, origin_distance_, step_, max_steps_, back) ||
      !traceStreamline(field_, start, +1.0, 1, insertion_distance_, step_, max_steps_, forward)) {
    return false;
  }
  std::vector<Eigen::Vector3d> points;
  for (auto it = back.rbegin(); it != back.rend(); ++it) points.push_back(*it);
  points.push_back(start);
  points.insert(points.end(), forward.begin(), forward.end());
  // End exactly on the attachment: continue the last step until it meets the patch (distinct streamlines meet it
  // at distinct points, unlike closest-point projection, which sends neighbours to the same patch vertex).
  // If that exit is not on the patch (the last step ran along the surface), the streamline keeps its own end,
  // which lies in a Dirichlet voxel next to the patch.
  Eigen::Vector3d hit;
  if (points.size() >= 2 && rayExit(surface_, points[1], points[0], 3 * h_, hit) &&
      origin_distance_.distance(hit) <= h_) {
    points.insert(points.begin(), hit);
  }
  if (points.size() >= 2 && rayExit(surface_, points[points.size() - 2], points.back(), 3 * h_, hit) &&
      insertion_distance_.distance(hit) <= h_) {
    points.push_back(hit);
  }
  fibre = resample(points, options_.points_per_fibre);
  return true;
}

}  // namespace muscle_deformation::fibre_steps
