// The spring-mesh SSD facial tracker (Voice Puppetry §4.1). See tracker.hpp for the method.
#include "voicepuppet/tracker.hpp"

#include <Eigen/LU>


#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <utility>

namespace voicepuppet {

void check_grey_image(const GreyImage& image, const char* name) {
  if (image.data == nullptr) {
    fail_argument(name, " has no pixel data (null pointer); pass a decoded 8-bit grey frame");
  }
  if (image.width < 1 || image.height < 1) {
    fail_argument(name, " must have a positive size, got ", image.width, " x ", image.height,
                  " (width x height); the frame is empty");
  }
  if (image.stride < image.width) {
    fail_argument(name, " stride must be at least its width (", image.width, " bytes), got ",
                  image.stride, "; pass the row pitch of the 8-bit grey buffer");
  }
}

// ------------------------------------------------------------------------------- Delaunay

namespace {

struct Triangle {
  std::array<Index, 3> v;
  double cx, cy, r2;  // circumcircle
};

bool circumcircle(const RowMatrixXd& p, Index a, Index b, Index c, Triangle& t) {
  const double ax = p(a, 0), ay = p(a, 1), bx = p(b, 0), by = p(b, 1), cx = p(c, 0),
               cy = p(c, 1);
  const double d = 2.0 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by));
  if (std::abs(d) < 1e-300) return false;
  const double a2 = ax * ax + ay * ay, b2 = bx * bx + by * by, c2 = cx * cx + cy * cy;
  t.v = {a, b, c};
  t.cx = (a2 * (by - cy) + b2 * (cy - ay) + c2 * (ay - by)) / d;
  t.cy = (a2 * (cx - bx) + b2 * (ax - cx) + c2 * (bx - ax)) / d;
  t.r2 = (ax - t.cx) * (ax - t.cx) + (ay - t.cy) * (ay - t.cy);
  return true;
}

}  // namespace

EdgeMatrix delaunay_edges(const MatrixRef& points) {
  if (points.cols() != 2) {
    fail_argument("points must have shape (P, 2) (x, y per row), got ", shape_of(points));
  }
  const Index n = points.rows();
  if (n < 3) {
    fail_argument("points must hold at least 3 points for a triangulation, got ", n,
                  "; a spring mesh needs at least one triangle");
  }
  require_finite(points, "points");
  // Normalise to the unit box so the tolerances below are scale-free.
  const double lox = points.col(0).minCoeff(), loy = points.col(1).minCoeff();
  const double extent = std::max(points.col(0).maxCoeff() - lox, points.col(1).maxCoeff() - loy);
  if (!(extent > 0)) fail_argument("points are all identical; give distinct landmark positions");
  RowMatrixXd p(n + 3, 2);
  for (Index i = 0; i < n; ++i) {
    p(i, 0) = (points(i, 0) - lox) / extent;
    p(i, 1) = (points(i, 1) - loy) / extent;
  }
  for (Index i = 0; i < n; ++i) {
    for (Index j = i + 1; j < n; ++j) {
      if ((p.row(i) - p.row(j)).squaredNorm() < 1e-24) {
        fail_argument("points ", i, " and ", j, " coincide at (", points(i, 0), ", ",
                      points(i, 1), "); remove duplicate landmarks");
      }
    }
  }
  // Super-triangle enclosing a disk of radius R around the unit box.
  const double R = 1e3;
  p.row(n) << 0.5, 0.5 + 2 * R;
  p.row(n + 1) << 0.5 - std::sqrt(3.0) * R, 0.5 - R;
  p.row(n + 2) << 0.5 + std::sqrt(3.0) * R, 0.5 - R;
  std::vector<Triangle> tris(1);
  circumcircle(p, n, n + 1, n + 2, tris[0]);

  std::vector<std::pair<Index, Index>> boundary;
  std::vector<Triangle> kept;
  for (Index k = 0; k < n; ++k) {
    const double x = p(k, 0), y = p(k, 1);
    boundary.clear();
    kept.clear();
    std::vector<Triangle> bad;
    for (const Triangle& t : tris) {
      const double d2 = (x - t.cx) * (x - t.cx) + (y - t.cy) * (y - t.cy);
      (d2 < t.r2 * (1 + 1e-12) ? bad : kept).push_back(t);
    }
    // Boundary of the cavity: edges of bad triangles not shared by two of them.
    for (const Triangle& t : bad) {
      for (int e = 0; e < 3; ++e) {
        Index a = t.v[e], b = t.v[(e + 1) % 3];
        if (a > b) std::swap(a, b);
        auto it = std::find(boundary.begin(), boundary.end(), std::make_pair(a, b));
        if (it != boundary.end()) {
          boundary.erase(it);
        } else {
          boundary.emplace_back(a, b);
        }
      }
    }
    for (const auto& [a, b] : boundary) {
      Triangle t;
      if (circumcircle(p, a, b, k, t)) kept.push_back(t);
    }
    tris.swap(kept);
  }
  std::vector<std::pair<Index, Index>> edges;
  for (const Triangle& t : tris) {
    if (t.v[0] >= n || t.v[1] >= n || t.v[2] >= n) continue;
    for (int e = 0; e < 3; ++e) {
      Index a = t.v[e], b = t.v[(e + 1) % 3];
      if (a > b) std::swap(a, b);
      edges.emplace_back(a, b);
    }
  }
  if (edges.empty()) {
    fail_argument("points are all on one line, so they have no triangulation; "
                  "give points that span an area, or pass the spring edges explicitly");
  }
  std::sort(edges.begin(), edges.end());
  edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
  EdgeMatrix out(static_cast<Index>(edges.size()), 2);
  for (Index e = 0; e < out.rows(); ++e) {
    out(e, 0) = edges[e].first;
    out(e, 1) = edges[e].second;
  }
  return out;
}

// ------------------------------------------------------------------------------- springs

namespace {

void check_points(const MatrixRef& points, const char* name) {
  if (points.cols() != 2) {
    fail_argument(name, " must have shape (P, 2) (x, y per row), got ", shape_of(points));
  }
  require_finite(points, name);
}

void check_edges(const EdgeMatrix& edges, Index n_points) {
  for (Index e = 0; e < edges.rows(); ++e) {
    const Index a = edges(e, 0), b = edges(e, 1);
    if (a < 0 || b < 0 || a >= n_points || b >= n_points) {
      fail_argument("edges row ", e, " = (", a, ", ", b, ") indexes outside the ", n_points,
                    " points; indices must be in [0, ", n_points - 1, "]");
    }
    if (a == b) fail_argument("edges row ", e, " joins point ", a, " to itself; remove it");
  }
}

void check_mesh(const SpringMesh& mesh, Index n_points) {
  check_edges(mesh.edges, n_points);
  const Index ne = mesh.edges.rows();
  if (mesh.rest_length.size() != ne || mesh.stiffness.size() != ne) {
    fail_argument("mesh must have one rest length and one stiffness per edge (", ne,
                  " edges), got ", mesh.rest_length.size(), " and ", mesh.stiffness.size());
  }
  for (Index e = 0; e < ne; ++e) {
    if (!(std::isfinite(mesh.rest_length[e]) && mesh.rest_length[e] > 0)) {
      fail_argument("mesh rest_length[", e, "] must be a positive length in pixels, got ",
                    mesh.rest_length[e]);
    }
    if (!(std::isfinite(mesh.stiffness[e]) && mesh.stiffness[e] >= 0)) {
      fail_argument("mesh stiffness[", e, "] must be finite and >= 0, got ", mesh.stiffness[e]);
    }
  }
  const bool has_p = mesh.offset_precision.size() != 0, has_m = mesh.offset_mean.size() != 0;
  if (has_p != has_m) {
    fail_argument("mesh offset_precision and offset_mean must be given together (or both empty), "
                  "got shapes ", shape_of(mesh.offset_precision), " and ", shape_of(mesh.offset_mean));
  }
  if (!has_p) return;
  if (mesh.offset_precision.rows() != ne || mesh.offset_precision.cols() != 4) {
    fail_argument("mesh offset_precision must have shape (", ne, ", 4) (a row-major 2x2 "
                  "precision per edge), got ", shape_of(mesh.offset_precision));
  }
  if (mesh.offset_mean.rows() != ne || mesh.offset_mean.cols() != 2) {
    fail_argument("mesh offset_mean must have shape (", ne, ", 2) (a mean offset per edge), got ",
                  shape_of(mesh.offset_mean));
  }
  require_finite(mesh.offset_precision, "mesh offset_precision");
  require_finite(mesh.offset_mean, "mesh offset_mean");
  for (Index e = 0; e < ne; ++e) {
    const double a = mesh.offset_precision(e, 0), b = mesh.offset_precision(e, 1),
                 c = mesh.offset_precision(e, 2), d = mesh.offset_precision(e, 3);
    const double tol = 1e-9 * (std::abs(a) + std::abs(d) + 1e-300);
    if (std::abs(b - c) > tol || a < 0 || d < 0 || a * d - b * c < -tol * (std::abs(a) + std::abs(d))) {
      fail_argument("mesh offset_precision row ", e, " = (", a, ", ", b, ", ", c, ", ", d,
                    ") is not a symmetric positive semidefinite 2x2 matrix; give inverse covariances");
    }
  }
}

bool has_offset_spring(const SpringMesh& mesh, Index e) {
  return mesh.offset_precision.size() != 0 &&
         (mesh.offset_precision(e, 0) != 0 || mesh.offset_precision(e, 3) != 0);
}

void check_frame_points(const VectorXi& idx, Index n_points, const char* name) {
  if (idx.size() == 1) {
    fail_argument(name, " must hold at least 2 point indices (or none), got 1");
  }
  for (Index k = 0; k < idx.size(); ++k) {
    if (idx[k] < 0 || idx[k] >= n_points) {
      fail_argument(name, "[", k, "] = ", idx[k], " indexes outside the ", n_points,
                    " points; indices must be in [0, ", n_points - 1, "]");
    }
  }
}

// The frame points not flagged lost (into `idx`), or all of them when fewer than 2 are left:
// a lost point (occluded, off its feature) would pull the least-squares face frame with it.
template <class Lost>
void found_points(const VectorXi& frame_points, Lost&& is_lost, VectorXi& idx) {
  idx.resize(frame_points.size());
  Index n = 0;
  for (Index k = 0; k < frame_points.size(); ++k) {
    if (!is_lost(frame_points[k])) idx[n++] = frame_points[k];
  }
  if (n < 2) {
    idx = frame_points;
  } else {
    idx.conservativeResize(n);
  }
}

}  // namespace

SpringMesh springs_from_points(const MatrixRef& points, const EdgeMatrix& edges,
                               double relative_sigma, double min_sigma) {
  check_points(points, "points");
  check_edges(edges, points.rows());
  if (!(std::isfinite(relative_sigma) && relative_sigma > 0)) {
    fail_argument("relative_sigma must be a positive fraction of each spring length, got ",
                  relative_sigma);
  }
  if (!(std::isfinite(min_sigma) && min_sigma >= 0)) {
    fail_argument("min_sigma must be a finite length in pixels >= 0, got ", min_sigma);
  }
  SpringMesh mesh;
  mesh.edges = edges;
  mesh.rest_length.resize(edges.rows());
  mesh.stiffness.resize(edges.rows());
  for (Index e = 0; e < edges.rows(); ++e) {
    const double len = (points.row(edges(e, 1)) - points.row(edges(e, 0))).norm();
    if (!(len > 0)) {
      fail_argument("edges row ", e, " joins points ", edges(e, 0), " and ", edges(e, 1),
                    ", which coincide; remove duplicate landmarks");
    }
    mesh.rest_length[e] = len;
    const double sigma = std::max(relative_sigma * len, min_sigma);
    mesh.stiffness[e] = 1.0 / (sigma * sigma);
  }
  return mesh;
}

Eigen::Matrix2d face_similarity(const MatrixRef& from, const MatrixRef& to, const VectorXi& idx) {
  Eigen::Matrix2d A = Eigen::Matrix2d::Identity();
  if (idx.size() < 2) return A;
  Eigen::Vector2d mf = Eigen::Vector2d::Zero(), mt = Eigen::Vector2d::Zero();
  for (Index k = 0; k < idx.size(); ++k) {
    mf += from.row(idx[k]).transpose();
    mt += to.row(idx[k]).transpose();
  }
  mf /= static_cast<double>(idx.size());
  mt /= static_cast<double>(idx.size());
  // Complex least squares: z_to ≈ (a + ib) z_from for the centred points.
  double num_re = 0, num_im = 0, den = 0;
  for (Index k = 0; k < idx.size(); ++k) {
    const double fx = from(idx[k], 0) - mf[0], fy = from(idx[k], 1) - mf[1];
    const double tx = to(idx[k], 0) - mt[0], ty = to(idx[k], 1) - mt[1];
    num_re += fx * tx + fy * ty;
    num_im += fx * ty - fy * tx;
    den += fx * fx + fy * fy;
  }
  if (!(den > 0)) return A;
  const double a = num_re / den, b = num_im / den;
  if (!(a * a + b * b > 1e-12)) return A;
  A << a, -b, b, a;
  return A;
}

namespace {

// The face frame of `to` relative to `from` from the frame points `idx` (see
// `face_similarity`), robust to frame points that slid off their feature (an eye corner in a
// blink), which would tilt and scale the least-squares face frame for all the others. When the
// least-squares fit leaves every point within the floor (2 % of the points' RMS radius, at the
// face's scale), it is the answer. Otherwise the similarity through the pair of points whose
// exact fit leaves the smallest median residual over all of them (least median of squares over
// the 2n pairs (k, k + ⌊n/2⌋) and (k, k + ⌊n/3⌋), mod n: a point off its feature spoils four of
// them) picks the inliers, those within 3 robust standard deviations of it (1.4826 · median
// residual, at least the floor), and the least-squares fit to the inliers is returned. `idx` is
// left holding the inliers.
Eigen::Matrix2d robust_similarity(const MatrixRef& from, const MatrixRef& to, VectorXi& idx) {
  const Index n = idx.size();
  const Eigen::Matrix2d A = face_similarity(from, to, idx);
  if (n < 4) return A;
  Eigen::Vector2d mf = Eigen::Vector2d::Zero(), mt = Eigen::Vector2d::Zero();
  for (Index k = 0; k < n; ++k) {
    mf += from.row(idx[k]).transpose();
    mt += to.row(idx[k]).transpose();
  }
  mf /= static_cast<double>(n);
  mt /= static_cast<double>(n);
  double spread = 0, worst = 0;
  for (Index k = 0; k < n; ++k) {
    const Eigen::Vector2d f = from.row(idx[k]).transpose() - mf;
    spread += f.squaredNorm();
    worst = std::max(worst, (to.row(idx[k]).transpose() - mt - A * f).norm());
  }
  const double floor = 0.02 * std::sqrt(spread / static_cast<double>(n) * std::abs(A.determinant()));
  if (worst <= floor) return A;
  std::vector<double> res(static_cast<size_t>(n)), best_res(static_cast<size_t>(n)), scratch(static_cast<size_t>(n));
  double best = std::numeric_limits<double>::infinity();
  for (const Index step : {n / 2, n / 3}) {
    for (Index a = 0; a < n; ++a) {
      const Index b = (a + step) % n;
      const double fx = from(idx[b], 0) - from(idx[a], 0), fy = from(idx[b], 1) - from(idx[a], 1);
      const double tx = to(idx[b], 0) - to(idx[a], 0), ty = to(idx[b], 1) - to(idx[a], 1);
      const double den = fx * fx + fy * fy;
      if (!(den > 0)) continue;
      // (c + i d) = (tx + i ty) / (fx + i fy): the similarity mapping a onto a and b onto b.
      const double c = (tx * fx + ty * fy) / den, d = (ty * fx - tx * fy) / den;
      for (Index k = 0; k < n; ++k) {
        const double ux = from(idx[k], 0) - from(idx[a], 0), uy = from(idx[k], 1) - from(idx[a], 1);
        const double ex = to(idx[a], 0) + c * ux - d * uy - to(idx[k], 0);
        const double ey = to(idx[a], 1) + d * ux + c * uy - to(idx[k], 1);
        res[static_cast<size_t>(k)] = std::hypot(ex, ey);
      }
      std::copy(res.begin(), res.end(), scratch.begin());
      std::nth_element(scratch.begin(), scratch.begin() + n / 2, scratch.end());
      const double med = scratch[static_cast<size_t>(n / 2)];
      if (med < best) {
        best = med;
        best_res.swap(res);
      }
    }
  }
  if (!(best < std::numeric_limits<double>::infinity())) return A;
  const double limit = std::max(3.0 * 1.4826 * best, floor);
  VectorXi inliers(n);
  Index kept = 0;
  for (Index k = 0; k < n; ++k) {
    if (best_res[static_cast<size_t>(k)] <= limit) inliers[kept++] = idx[k];
  }
  if (kept == n || kept < 2) return A;
  idx = inliers.head(kept);
  return face_similarity(from, to, idx);
}

}  // namespace

SpringMesh estimate_springs(const MatrixRef& tracks, const RowMatrixXb& lost,
                            const SpringMesh& previous, double min_sigma,
                            const VectorXi& frame_points) {
  const Index T = tracks.rows();
  if (tracks.cols() % 2 != 0 || tracks.cols() < 6) {
    fail_argument("tracks must have shape (T, 2*P) with P >= 3 (x0, y0, x1, y1, ... per frame), "
                  "got ", shape_of(tracks));
  }
  const Index P = tracks.cols() / 2;
  if (lost.rows() != T || lost.cols() != P) {
    fail_argument("lost must have shape (", T, ", ", P, ") (one flag per frame and point), got ",
                  shape_of(lost));
  }
  require_finite(tracks, "tracks");
  check_mesh(previous, P);
  if (!(std::isfinite(min_sigma) && min_sigma > 0)) {
    fail_argument("min_sigma must be a positive length in pixels, got ", min_sigma);
  }
  check_frame_points(frame_points, P, "frame_points");
  SpringMesh mesh = previous;
  // Face frame of every frame: A_t^-1 maps frame t's offsets into frame 0's, so lengths and
  // offsets are measured in the face frame (the tracker scales them back with the face).
  std::vector<Eigen::Matrix2d> to_face;
  const bool face_frame = frame_points.size() != 0;
  if (face_frame) {
    to_face.resize(static_cast<size_t>(T));
    RowMatrixXd first(P, 2), frame_t(P, 2);
    for (Index i = 0; i < P; ++i) first.row(i) << tracks(0, 2 * i), tracks(0, 2 * i + 1);
    VectorXi idx;
    for (Index t = 0; t < T; ++t) {
      for (Index i = 0; i < P; ++i) frame_t.row(i) << tracks(t, 2 * i), tracks(t, 2 * i + 1);
      found_points(frame_points, [&](Index i) { return lost(t, i); }, idx);
      to_face[static_cast<size_t>(t)] = robust_similarity(first, frame_t, idx).inverse();
    }
  }
  if (!face_frame && mesh.offset_precision.size() != 0) {
    to_face.assign(static_cast<size_t>(T), Eigen::Matrix2d::Identity());  // the image frame
  }
  std::vector<double> d, dev;
  std::vector<Index> frames;
  for (Index e = 0; e < mesh.edges.rows(); ++e) {
    const Index a = mesh.edges(e, 0), b = mesh.edges(e, 1);
    d.clear();
    frames.clear();
    for (Index t = 0; t < T; ++t) {
      if (lost(t, a) || lost(t, b)) continue;
      const Eigen::Vector2d dv(tracks(t, 2 * b) - tracks(t, 2 * a), tracks(t, 2 * b + 1) - tracks(t, 2 * a + 1));
      const Eigen::Vector2d fv = face_frame ? Eigen::Vector2d(to_face[static_cast<size_t>(t)] * dv) : dv;
      d.push_back(std::hypot(fv[0], fv[1]));
      frames.push_back(t);
    }
    if (d.size() < 2) continue;
    // Frames where a tracker sat on the wrong feature would inflate the variance and soften the
    // very spring that should pull it back: keep the distances within 3 robust standard
    // deviations (1.4826 * median absolute deviation) of the median, then take the mean and
    // variance of those.
    const auto median = [](std::vector<double> v) {
      const size_t h = v.size() / 2;
      std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(h), v.end());
      double m = v[h];
      if (v.size() % 2 == 0) m = 0.5 * (m + *std::max_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(h)));
      return m;
    };
    const double med = median(d);
    dev.resize(d.size());
    for (size_t k = 0; k < d.size(); ++k) dev[k] = std::abs(d[k] - med);
    const double band = 3.0 * std::max(1.4826 * median(dev), min_sigma);
    double mean = 0, m2 = 0;  // Welford's running mean and variance
    Index count = 0;
    Eigen::Vector2d fmean = Eigen::Vector2d::Zero();  // ... and of the face-frame offsets
    Eigen::Matrix2d fm2 = Eigen::Matrix2d::Zero();
    const bool offset = has_offset_spring(mesh, e);
    for (size_t k = 0; k < d.size(); ++k) {
      const double x = d[k];
      if (std::abs(x - med) > band) continue;
      ++count;
      const double delta = x - mean;
      mean += delta / static_cast<double>(count);
      m2 += delta * (x - mean);
      if (offset) {
        const Index t = frames[k];
        const Eigen::Vector2d f = to_face[static_cast<size_t>(t)] *
            Eigen::Vector2d(tracks(t, 2 * b) - tracks(t, 2 * a), tracks(t, 2 * b + 1) - tracks(t, 2 * a + 1));
        const Eigen::Vector2d fd = f - fmean;
        fmean += fd / static_cast<double>(count);
        fm2 += fd * (f - fmean).transpose();
      }
    }
    if (count < 2 || !(mean > 0)) continue;
    const double var = m2 / static_cast<double>(count - 1);
    mesh.rest_length[e] = mean;
    mesh.stiffness[e] = 1.0 / std::max(var, min_sigma * min_sigma);
    if (offset) {
      // Precision = inverse covariance with its eigenvalues floored at min_sigma²; the length
      // spring is off (the offset spring's Gaussian already holds the length statistics).
      // Closed-form eigen-decomposition of the symmetric 2x2 covariance [[p, q], [q, r]].
      const double n1 = static_cast<double>(count - 1);
      const double cp = fm2(0, 0) / n1, cq = 0.5 * (fm2(0, 1) + fm2(1, 0)) / n1, cr = fm2(1, 1) / n1;
      const double mid = 0.5 * (cp + cr), half = std::hypot(0.5 * (cp - cr), cq);
      const double floor2 = min_sigma * min_sigma;
      const double l1 = std::max(mid + half, floor2), l2 = std::max(mid - half, floor2);
      const double phi = 0.5 * std::atan2(2 * cq, cp - cr), c = std::cos(phi), sn = std::sin(phi);
      // precision = v1 v1^T / l1 + v2 v2^T / l2 with v1 = (c, s), v2 = (-s, c)
      const double pxx = c * c / l1 + sn * sn / l2, pxy = c * sn * (1 / l1 - 1 / l2),
                   pyy = sn * sn / l1 + c * c / l2;
      mesh.offset_precision.row(e) << pxx, pxy, pxy, pyy;
      mesh.offset_mean(e, 0) = fmean[0];
      mesh.offset_mean(e, 1) = fmean[1];
      mesh.stiffness[e] = 0.0;
    }
  }
  return mesh;
}

// ------------------------------------------------------------------------------- tracker

namespace {

// One pyramid level: an 8-bit image, either borrowed (level 0) or owned.
struct Level {
  const std::uint8_t* data = nullptr;
  Index width = 0, height = 0, stride = 0;
  std::vector<std::uint8_t> owned;
};

// 2x2 box average and decimation: pixel (x, y) of level l+1 sits at (2x + 0.5, 2y + 0.5) of l.
void downsample(const Level& src, Level& dst) {
  const Index w = src.width / 2, h = src.height / 2, sstride = src.stride;
  dst.width = w;
  dst.height = h;
  dst.stride = w;
  dst.owned.resize(static_cast<size_t>(w * h));
  const std::uint8_t* in = src.data;
  std::uint8_t* outp = dst.owned.data();
  for (Index y = 0; y < h; ++y) {
    const std::uint8_t* __restrict r0 = in + (2 * y) * sstride;
    const std::uint8_t* __restrict r1 = r0 + sstride;
    std::uint8_t* __restrict out = outp + y * w;
    for (Index x = 0; x < w; ++x) {
      const unsigned sum = unsigned(r0[2 * x]) + r0[2 * x + 1] + r1[2 * x] + r1[2 * x + 1] + 2u;
      out[x] = static_cast<std::uint8_t>(sum >> 2);
    }
  }
  dst.data = dst.owned.data();
}

// Bilinear samples of the (2q+1)² grid centred at (cx, cy); returns the fraction of samples
// inside the image (outside ones take the nearest border pixel).
double sample_patch(const Level& im, double cx, double cy, int q, float* out) {
  const int m = 2 * q + 1;
  const double fxf = std::floor(cx), fyf = std::floor(cy);
  const float fx = static_cast<float>(cx - fxf), fy = static_cast<float>(cy - fyf);
  const float w00 = (1 - fx) * (1 - fy), w01 = fx * (1 - fy), w10 = (1 - fx) * fy, w11 = fx * fy;
  const Index x0 = static_cast<Index>(fxf) - q, y0 = static_cast<Index>(fyf) - q;
  if (x0 >= 0 && y0 >= 0 && x0 + m < im.width && y0 + m < im.height) {
    for (int j = 0; j < m; ++j) {
      const std::uint8_t* r0 = im.data + (y0 + j) * im.stride + x0;
      const std::uint8_t* r1 = r0 + im.stride;
      float* o = out + j * m;
      for (int i = 0; i < m; ++i) {
        o[i] = w00 * r0[i] + w01 * r0[i + 1] + w10 * r1[i] + w11 * r1[i + 1];
      }
    }
    return 1.0;
  }
  Index inside = 0;
  auto px = [&](Index x, Index y) -> float {
    x = std::clamp<Index>(x, 0, im.width - 1);
    y = std::clamp<Index>(y, 0, im.height - 1);
    return im.data[y * im.stride + x];
  };
  for (int j = 0; j < m; ++j) {
    const Index y = y0 + j;
    for (int i = 0; i < m; ++i) {
      const Index x = x0 + i;
      const double sx = static_cast<double>(x) + fx, sy = static_cast<double>(y) + fy;
      if (sx >= 0 && sy >= 0 && sx <= static_cast<double>(im.width - 1) &&
          sy <= static_cast<double>(im.height - 1)) {
        ++inside;
      }
      out[j * m + i] =
          w00 * px(x, y) + w01 * px(x + 1, y) + w10 * px(x, y + 1) + w11 * px(x + 1, y + 1);
    }
  }
  return static_cast<double>(inside) / static_cast<double>(m * m);
}

// Bilinear samples of the (2q+1)² grid (u, v) in [-q, q]² mapped to (cx, cy) + M (u, v): a
// patch seen through the similarity M (rotated and scaled), outside samples taking the nearest
// border pixel. Returns the fraction of samples inside the image.
double sample_warped(const Level& im, double cx, double cy, int q, const Eigen::Matrix2d& M,
                     float* out) {
  const int m = 2 * q + 1;
  Index inside = 0;
  auto px = [&](Index x, Index y) -> float {
    x = std::clamp<Index>(x, 0, im.width - 1);
    y = std::clamp<Index>(y, 0, im.height - 1);
    return im.data[y * im.stride + x];
  };
  const double xmax = static_cast<double>(im.width - 1), ymax = static_cast<double>(im.height - 1);
  for (int j = 0; j < m; ++j) {
    for (int i = 0; i < m; ++i) {
      const double u = i - q, v = j - q;
      const double sx = cx + M(0, 0) * u + M(0, 1) * v, sy = cy + M(1, 0) * u + M(1, 1) * v;
      if (sx >= 0 && sy >= 0 && sx <= xmax && sy <= ymax) ++inside;
      const double fxf = std::floor(sx), fyf = std::floor(sy);
      const float fx = static_cast<float>(sx - fxf), fy = static_cast<float>(sy - fyf);
      const Index x = static_cast<Index>(fxf), y = static_cast<Index>(fyf);
      out[j * m + i] = (1 - fx) * (1 - fy) * px(x, y) + fx * (1 - fy) * px(x + 1, y) +
                       (1 - fx) * fy * px(x, y + 1) + fx * fy * px(x + 1, y + 1);
    }
  }
  return static_cast<double>(inside) / static_cast<double>(m * m);
}

// A template patch at one pyramid level: zero-mean values and gradients, contrast, Hessian.
struct Template {
  std::vector<float> t, gx, gy;
  std::vector<float> mask;  // 1 on the pixels the template uses, 0 elsewhere; empty: all of them
  int n_used = 0;           // pixels used
  double sigma = 0;  // RMS of t (contrast)
  double hxx = 0, hxy = 0, hyy = 0;
};

// Result of comparing the image around a point with a template.
struct Match {
  double ncc = 0;     // zero-mean normalised cross-correlation
  double bx = 0, by = 0;  // sum of gradient * residual
  double inside = 0;  // fraction of the patch inside the image
  bool textured = false;
};

constexpr double kMinContrast = 0.5;  // grey levels RMS below which a patch is flat
constexpr int kLanes = 16;  // accumulator lanes of the patch sums (n_pad is a multiple)
constexpr double kCoarseFloor = 0.2;
constexpr double kSearchMargin = 0.05;  // a searched point moves only for a clearly better match
constexpr double kSearchPenalty = 0.1;  // score lost by a search move of the full radius
constexpr int kGroupSlack = 2;  // px each point of a jointly searched group may deviate
// px: the first-frame templates are re-cut through the current pose when it has moved further
// than this at the corner of a patch since they were last cut (or from the identity)
constexpr double kWarpTolerance = 0.2;

}  // namespace

struct SpringMeshTracker::Impl {
  TrackerOptions opt;
  SpringMesh mesh;
  Index P = 0, width = 0, height = 0, n_levels = 1;
  int r = 0, n_pix = 0, n_pad = 0;  // patch pixels, and rounded up to a multiple of kLanes
  RowMatrixXd pts;
  RowMatrixXd sides;  // #P by 2 half-patch directions (a zero row: whole patch), or empty
  std::vector<double> prev_weight;  // data weight of each point at the end of the last frame
  RowMatrixXd init_pts;             // the first frame's points (the face frame's reference)
  std::vector<char> muted;          // points whose data term this frame's relaxations ignore
  RowMatrixXd anchors;              // this frame's anchors (NaN: none), or empty
  std::vector<char> checked;        // points held by an offset spring (the consistency check)
  Eigen::Matrix2d to_face = Eigen::Matrix2d::Identity();  // this frame's A^-1 (offset springs)
  std::vector<Level> pyr;
  // templates[(l * P + i)] for the first frame and for the current (guarded) template.
  std::vector<Template> first, current;
  // Work buffers.
  std::vector<float> patch, big, window;
  std::vector<double> nccs;
  std::vector<std::vector<double>> group_maps;
  std::vector<Template> reference;  // finest-level first-frame templates of the reference search
  // Head pose. `pose` is this frame's similarity A (from the first frame's `frame_points` to
  // the previous frame's; the identity without frame points), `face_scale` its scale. The
  // first-frame templates in `first` and `reference` are `first_base` and `reference_base`
  // (cut from the first frame, kept in `first_pyr`) seen through `warp`, a recent pose
  // (`warped`: not the identity), re-cut when the pose moves on by more than kWarpTolerance.
  Eigen::Matrix2d pose = Eigen::Matrix2d::Identity();
  double face_scale = 1.0;
  Eigen::Matrix2d warp = Eigen::Matrix2d::Identity(), warp_inv = Eigen::Matrix2d::Identity();
  bool warped = false;
  std::vector<char> prev_lost;  // lost flags of the previous frame (its lost points give no pose)
  VectorXi pose_idx;
  std::vector<Level> first_pyr;
  std::vector<Template> first_base, reference_base;
  std::vector<std::pair<int, float>> used_px;
  RowMatrixXd A;
  // The Gauss-Newton system in block form: 2x2 diagonal blocks per point, one 2x2 coupling
  // block per edge (the spring's -k u u^T), solved by block-Jacobi preconditioned conjugate
  // gradients (the system is SPD; a few dozen unknowns, ~3 couplings per point).
  std::vector<Eigen::Matrix2d> diag, coupling, inv;
  std::vector<Eigen::Vector2d> rhs, delta, res, z, dir, adir;

  void multiply(const std::vector<Eigen::Vector2d>& x, std::vector<Eigen::Vector2d>& y) const {
    for (Index i = 0; i < P; ++i) y[i] = diag[i] * x[i];
    for (Index e = 0; e < mesh.edges.rows(); ++e) {
      const Index a = mesh.edges(e, 0), b = mesh.edges(e, 1);
      y[a].noalias() += coupling[e] * x[b];
      y[b].noalias() += coupling[e] * x[a];
    }
  }

  void solve() {
    double bnorm = 0;
    for (Index i = 0; i < P; ++i) {
      const Eigen::Matrix2d& d = diag[i];
      const double det = d(0, 0) * d(1, 1) - d(0, 1) * d(1, 0);
      if (!(det > 0) || !(d(0, 0) > 0)) {
        fail_numeric("spring-mesh tracker: the Gauss-Newton system is not positive definite at "
                     "point ", i, "; check the options (damping > 0) and the spring stiffnesses");
      }
      inv[i] << d(1, 1) / det, -d(0, 1) / det, -d(1, 0) / det, d(0, 0) / det;
      delta[i].setZero();
      res[i] = rhs[i];
      z[i] = inv[i] * res[i];
      dir[i] = z[i];
      bnorm += rhs[i].squaredNorm();
    }
    if (bnorm == 0) return;
    double rz = 0;
    for (Index i = 0; i < P; ++i) rz += res[i].dot(z[i]);
    for (Index it = 0; it < 4 * P; ++it) {
      multiply(dir, adir);
      double pap = 0;
      for (Index i = 0; i < P; ++i) pap += dir[i].dot(adir[i]);
      if (!(pap > 0)) break;
      const double alpha = rz / pap;
      double rr = 0, rz_new = 0;
      for (Index i = 0; i < P; ++i) {
        delta[i] += alpha * dir[i];
        res[i] -= alpha * adir[i];
        rr += res[i].squaredNorm();
      }
      if (rr <= 1e-20 * bnorm) break;
      for (Index i = 0; i < P; ++i) {
        z[i] = inv[i] * res[i];
        rz_new += res[i].dot(z[i]);
      }
      const double beta = rz_new / rz;
      rz = rz_new;
      for (Index i = 0; i < P; ++i) dir[i] = z[i] + beta * dir[i];
    }
  }

  static double level_coord(double p0, Index l) {
    return (p0 + 0.5) / static_cast<double>(Index(1) << l) - 0.5;
  }

  void build_pyramid(const GreyImage& im) {
    pyr.resize(static_cast<size_t>(n_levels));
    pyr[0].data = im.data;
    pyr[0].width = im.width;
    pyr[0].height = im.height;
    pyr[0].stride = im.stride;
    for (Index l = 1; l < n_levels; ++l) downsample(pyr[l - 1], pyr[l]);
  }

  // Builds point i's template `tpl` from the current pyramid at level l around level-0
  // position (x, y), on the half of the patch its side vector selects (all of it without one).
  // Returns the fraction of the patch inside the image.
  // `side` (optional) replaces the point's own side vector. Sides are first-frame directions:
  // they turn with the face (`warp`). With `src`, the patch is cut from that pyramid (the
  // first frame's) seen through `warp`: pixel offset u of the template samples src at
  // (x, y) + warp⁻¹ u, so a first-frame template looks as the face does now.
  double make_template(Index l, Index i, double x, double y, Template& tpl,
                       const Eigen::Vector2d* side = nullptr, const std::vector<Level>* src = nullptr) {
    const int q = r + 1, m = 2 * q + 1, n = 2 * r + 1;
    const double inside =
        src ? sample_warped((*src)[static_cast<size_t>(l)], level_coord(x, l), level_coord(y, l), q,
                            warp_inv, big.data())
            : sample_patch(pyr[l], level_coord(x, l), level_coord(y, l), q, big.data());
    tpl.t.assign(n_pad, 0.0f);
    tpl.gx.assign(n_pad, 0.0f);
    tpl.gy.assign(n_pad, 0.0f);
    Eigen::Vector2d sv(side ? (*side)[0] : sides.size() ? sides(i, 0) : 0.0,
                       side ? (*side)[1] : sides.size() ? sides(i, 1) : 0.0);
    if (warped) sv = warp * sv;
    const double sx = sv[0], sy = sv[1];
    const bool half = sx != 0 || sy != 0;
    tpl.mask.assign(half ? n_pad : 0, 0.0f);
    tpl.n_used = 0;
    double mt = 0, mgx = 0, mgy = 0;
    for (int j = 0; j < n; ++j) {
      for (int i2 = 0; i2 < n; ++i2) {
        const int c = (j + 1) * m + (i2 + 1), k = j * n + i2;
        // Half patch: the pixels strictly on the side of the line through the point that the
        // side vector points to (the lip, not the opening mouth next to it).
        if (half) {
          if ((i2 - r) * sx + (j - r) * sy <= 0) continue;
          tpl.mask[k] = 1.0f;
        }
        ++tpl.n_used;
        tpl.t[k] = big[c];
        // Scharr derivatives (3, 10, 3 smoothing across the difference), normalised to unit gain.
        tpl.gx[k] = (3.0f * (big[c - m + 1] - big[c - m - 1]) + 10.0f * (big[c + 1] - big[c - 1]) +
                     3.0f * (big[c + m + 1] - big[c + m - 1])) / 32.0f;
        tpl.gy[k] = (3.0f * (big[c + m - 1] - big[c - m - 1]) + 10.0f * (big[c + m] - big[c - m]) +
                     3.0f * (big[c + m + 1] - big[c - m + 1])) / 32.0f;
        mt += tpl.t[k];
        mgx += tpl.gx[k];
        mgy += tpl.gy[k];
      }
    }
    const int used = tpl.n_used;
    mt /= used;
    mgx /= used;
    mgy /= used;
    double vt = 0, hxx = 0, hxy = 0, hyy = 0;
    for (int k = 0; k < n_pix; ++k) {
      if (half && tpl.mask[k] == 0.0f) continue;
      tpl.t[k] = static_cast<float>(tpl.t[k] - mt);
      tpl.gx[k] = static_cast<float>(tpl.gx[k] - mgx);
      tpl.gy[k] = static_cast<float>(tpl.gy[k] - mgy);
      vt += double(tpl.t[k]) * tpl.t[k];
      hxx += double(tpl.gx[k]) * tpl.gx[k];
      hxy += double(tpl.gx[k]) * tpl.gy[k];
      hyy += double(tpl.gy[k]) * tpl.gy[k];
    }
    tpl.sigma = std::sqrt(vt / used);
    tpl.hxx = hxx;
    tpl.hxy = hxy;
    tpl.hyy = hyy;
    return inside;
  }

  // Compares the image at level l around level-0 position (x, y) with template `tpl`.
  Match match(Index l, double x, double y, const Template& tpl) {
    Match mt;
    mt.inside = sample_patch(pyr[l], level_coord(x, l), level_coord(y, l), r, patch.data());
    // Sums over n_pad = n_pix rounded up to kLanes, in kLanes independent accumulators so the
    // compiler can vectorise them; the padding is zero in the patch and in the templates.
    const float* __restrict I = patch.data();
    const float* __restrict T = tpl.t.data();
    const float* __restrict GX = tpl.gx.data();
    const float* __restrict GY = tpl.gy.data();
    const int used = tpl.n_used;
    float mf, s2f;
    if (tpl.mask.empty()) {
      float acc[kLanes] = {};
      for (int k = 0; k < n_pad; k += kLanes) {
        for (int j = 0; j < kLanes; ++j) acc[j] += I[k + j];
      }
      float sf = 0;
      for (int j = 0; j < kLanes; ++j) sf += acc[j];
      mf = sf / static_cast<float>(n_pix);
      float a2[kLanes] = {};  // centred second moment (no cancellation); pads add mf² each
      for (int k = 0; k < n_pad; k += kLanes) {
        for (int j = 0; j < kLanes; ++j) a2[j] += (I[k + j] - mf) * (I[k + j] - mf);
      }
      s2f = 0;
      for (int j = 0; j < kLanes; ++j) s2f += a2[j];
      s2f -= static_cast<float>(n_pad - n_pix) * mf * mf;
    } else {
      // Half patch: mean and contrast over the template's pixels only.
      const float* __restrict M = tpl.mask.data();
      float acc[kLanes] = {};
      for (int k = 0; k < n_pad; k += kLanes) {
        for (int j = 0; j < kLanes; ++j) acc[j] += M[k + j] * I[k + j];
      }
      float sf = 0;
      for (int j = 0; j < kLanes; ++j) sf += acc[j];
      mf = sf / static_cast<float>(used);
      float a2[kLanes] = {};
      for (int k = 0; k < n_pad; k += kLanes) {
        for (int j = 0; j < kLanes; ++j) a2[j] += M[k + j] * (I[k + j] - mf) * (I[k + j] - mf);
      }
      s2f = 0;
      for (int j = 0; j < kLanes; ++j) s2f += a2[j];
    }
    const double var = std::max(0.0, double(s2f) / used);
    const double sigma_i = std::sqrt(var);
    if (sigma_i < kMinContrast || tpl.sigma < kMinContrast) return mt;
    mt.textured = true;
    const float gain = static_cast<float>(tpl.sigma / sigma_i);
    float ac[kLanes] = {}, ax[kLanes] = {}, ay[kLanes] = {};
    for (int k = 0; k < n_pad; k += kLanes) {
      for (int j = 0; j < kLanes; ++j) {
        const float d = I[k + j] - mf;
        ac[j] += d * T[k + j];
        const float e = gain * d - T[k + j];
        ax[j] += GX[k + j] * e;
        ay[j] += GY[k + j] * e;
      }
    }
    float cross = 0, bx = 0, by = 0;
    for (int j = 0; j < kLanes; ++j) {
      cross += ac[j];
      bx += ax[j];
      by += ay[j];
    }
    // Template values and gradients are 0 off its pixels, so the sums above cover only those.
    mt.ncc = cross / (used * sigma_i * tpl.sigma);
    mt.bx = bx;
    mt.by = by;
    return mt;
  }


  double data_weight(const Match& m) const {
    if (!m.textured || m.inside < 0.5) return 0.0;
    const double w = (m.ncc - opt.ncc_floor) / (opt.ncc_full - opt.ncc_floor);
    return std::clamp(w, 0.0, 1.0);
  }

  // Exhaustive search for the half-patch points (the deforming ones: lips) that stage A left on
  // a poor match: the current template is correlated with the finest level at every
  // whole-pixel offset within `search_radius`, and a point moves to the best-scoring offset
  // when that correlates at least ncc_full and clearly better than where it is. A lip can move
  // 8 px between frames, beyond the reach of the gradient steps, and the coarse pyramid levels
  // do not see it: their patches are dominated by skin that barely moves. Returns whether any
  // point moved.
  // NCC of point i's template in `tpls` (finest level) with the image at every whole-pixel
  // offset (ox, oy), |ox|, |oy| <= S, from its position: out[(oy + S) * (2S + 1) + ox + S],
  // -2 where the image is flat. Returns false when the template itself is flat.
  bool ncc_map(Index i, int S, std::vector<double>& out, const std::vector<Template>& tpls,
               int reach = -1) {
    const Index l = 0;
    const Template& tpl = tpls[static_cast<size_t>(l * P + i)];
    const int side = 2 * S + 1;
    out.assign(static_cast<size_t>(side * side), -2.0);
    if (tpl.sigma < kMinContrast) return false;
    const int q = r + S, m = 2 * q + 1, n = 2 * r + 1;
    window.resize(static_cast<size_t>(m * m));
    sample_patch(pyr[l], level_coord(pts(i, 0), l), level_coord(pts(i, 1), l), q, window.data());
    // The template's pixels as (offset in the window, value): a half patch uses about half.
    used_px.clear();
    for (int j = 0; j < n; ++j) {
      for (int k = 0; k < n; ++k) {
        const int idx = j * n + k;
        if (!tpl.mask.empty() && tpl.mask[static_cast<size_t>(idx)] == 0.0f) continue;
        used_px.emplace_back(j * m + k, tpl.t[static_cast<size_t>(idx)]);
      }
    }
    const double used = tpl.n_used;
    const int reach2 = reach < 0 ? 2 * S * S : reach * reach;  // offsets beyond it are not needed
    for (int oy = -S; oy <= S; ++oy) {
      for (int ox = -S; ox <= S; ++ox) {
        if (ox * ox + oy * oy > reach2) continue;
        // The template is zero-mean on its pixels, so sum T·I is the centred cross term.
        const float* base = &window[static_cast<size_t>((S + oy) * m + S + ox)];
        double s1 = 0, s2 = 0, c = 0;
        for (const auto& [off, tv] : used_px) {
          const double v = base[off];
          s1 += v;
          s2 += v * v;
          c += tv * v;
        }
        const double mean = s1 / used;
        const double var = s2 / used - mean * mean;
        if (!(var > kMinContrast * kMinContrast)) continue;
        out[static_cast<size_t>((oy + S) * side + ox + S)] = c / (used * std::sqrt(var) * tpl.sigma);
      }
    }
    return true;
  }

  bool search() {
    const int S = static_cast<int>(std::ceil(opt.search_radius * warp_scale()));
    bool moved = false;
    if (S < 1) return moved;
    for (Index i = 0; i < P; ++i) {
      if (sides.size() == 0 || (sides(i, 0) == 0 && sides(i, 1) == 0)) continue;
      const Match m0 = match(0, pts(i, 0), pts(i, 1), current[static_cast<size_t>(i)]);
      if (m0.textured && m0.ncc >= opt.ncc_full) continue;  // stage A found it
      if (!ncc_map(i, S, nccs, current)) continue;
      moved = move_to_best(i, S, opt.ncc_full) || moved;
    }
    return moved;
  }

  // The best whole-pixel offset of point i in `nccs` (an `ncc_map` of radius S) within the
  // search disc: longer moves must correlate better (along a lip contour every offset matches
  // about as well), so the score loses kSearchPenalty at the disc's edge. The point moves there
  // when the score reaches `accept` and beats staying by kSearchMargin. Returns whether it moved.
  // With a unit direction `line`, only the offsets within half a pixel of that line count.
  bool move_to_best(Index i, int S, double accept, const Eigen::Vector2d* line = nullptr) {
    const int side = 2 * S + 1;
    double best = -2, here = -2;
    int bx = 0, by = 0;
    for (int oy = -S; oy <= S; ++oy) {
      for (int ox = -S; ox <= S; ++ox) {
        if (ox * ox + oy * oy > S * S) continue;
        if (line && std::abs(ox * (*line)[1] - oy * (*line)[0]) > 0.5) continue;
        const double ncc = nccs[static_cast<size_t>((oy + S) * side + ox + S)];
        if (ncc < -1.5) continue;
        const double score = ncc - kSearchPenalty * (ox * ox + oy * oy) / double(S * S);
        if (ox == 0 && oy == 0) here = score;
        if (score > best) {
          best = score;
          bx = ox;
          by = oy;
        }
      }
    }
    if ((bx == 0 && by == 0) || best < accept || !(best > here + kSearchMargin)) return false;
    pts(i, 0) += bx;
    pts(i, 1) += by;
    return true;
  }

  // Exhaustive search of `reference_points` against their first-frame templates (finest
  // level, whole-pixel offsets within `reference_search_radius`). A mouth corner's whole patch
  // matches the upper lip's edge beside it nearly as well as the corner, so the gradient steps
  // (and its current template, which may have followed the edge) leave it there as the mouth
  // opens; over a wider window its first-frame patch still peaks at the corner. Returns
  // whether any point moved.
  // A point with a `reference_sides` row is searched for with the half of its first-frame
  // patch on that side, and only along that direction (across the contour: along it a half
  // patch on a contour matches about equally well everywhere).
  bool reference_search() {
    const int S = static_cast<int>(std::ceil(opt.reference_search_radius * warp_scale()));
    bool moved = false;
    if (S < 1) return moved;
    for (Index q = 0; q < opt.reference_points.size(); ++q) {
      const Index i = opt.reference_points[q];
      if (!ncc_map(i, S, nccs, reference)) continue;
      Eigen::Vector2d dir;
      const Eigen::Vector2d* side = reference_side(i, dir);
      if (side) dir = (warp * dir).normalized();
      moved = move_to_best(i, S, opt.reference_search_ncc, side) || moved;
    }
    return moved;
  }

  // Joint search of each point group (`search_groups`: a lower lip that drops further between
  // two frames than the gradient steps reach, and whose points each have too faint a contour
  // to be found alone). Every common whole-pixel offset o within `group_search_radius` is
  // scored by the mean over the group of each point's best correlation with its first-frame
  // template (the lip's own texture, which a current template that followed a wrong feature no
  // longer holds) within kGroupSlack px of o (the points of a lip do not move exactly together),
  // less the search's distance penalty; the group moves (each point to its own best offset
  // near o) when the best o is clearly better than staying. Returns whether a group moved.
  bool group_search() {
    const int S = static_cast<int>(std::ceil(opt.group_search_radius * warp_scale()));
    if (S < 1 || opt.search_groups.size() == 0) return false;
    const int D = kGroupSlack, W = S + D, side = 2 * W + 1;
    const Index n_groups = opt.search_groups.maxCoeff() + 1;
    bool moved = false;
    std::vector<Index> members;
    for (Index g = 0; g < n_groups; ++g) {
      members.clear();
      for (Index i = 0; i < P; ++i) {
        if (opt.search_groups[i] == g) members.push_back(i);
      }
      // A group whose points all match where they are has been found: no search.
      double at = 0;
      for (const Index i : members) {
        const Match mi = match(0, pts(i, 0), pts(i, 1), first[static_cast<size_t>(i)]);
        at += mi.textured ? mi.ncc : -1.0;
      }
      if (members.empty() || at >= opt.ncc_full * static_cast<double>(members.size())) continue;
      group_maps.resize(members.size());
      std::vector<Index> used;
      // Offsets within the slack (Chebyshev) of the search disc lie within S + 1.5 D of 0.
      const int reach = S + (3 * D + 1) / 2;
      for (size_t k = 0; k < members.size(); ++k) {
        if (ncc_map(members[k], W, group_maps[k], first, reach)) used.push_back(static_cast<Index>(k));
      }
      if (used.size() < 2) continue;
      // Each point's best correlation, and where, within the slack around an offset.
      auto best_near = [&](size_t k, int ox, int oy, int& bx, int& by) {
        double b = -2;
        for (int dy = -D; dy <= D; ++dy) {
          for (int dx = -D; dx <= D; ++dx) {
            const double v = group_maps[k][static_cast<size_t>((oy + dy + W) * side + ox + dx + W)];
            if (v > b) {
              b = v;
              bx = ox + dx;
              by = oy + dy;
            }
          }
        }
        return b;
      };
      double best = -2, here = -2;
      int gx = 0, gy = 0;
      for (int oy = -S; oy <= S; ++oy) {
        for (int ox = -S; ox <= S; ++ox) {
          if (ox * ox + oy * oy > S * S) continue;
          double sum = 0;
          for (const Index k : used) {
            int bx, by;
            sum += std::max(best_near(static_cast<size_t>(k), ox, oy, bx, by), -1.0);
          }
          const double score = sum / static_cast<double>(used.size()) -
                               kSearchPenalty * (ox * ox + oy * oy) / double(S * S);
          if (ox == 0 && oy == 0) here = score;
          if (score > best) {
            best = score;
            gx = ox;
            gy = oy;
          }
        }
      }
      if ((gx == 0 && gy == 0) || !(best > here + kSearchMargin) || best < opt.ncc_floor) continue;
      for (const Index k : used) {
        int bx = 0, by = 0;
        best_near(static_cast<size_t>(k), gx, gy, bx, by);
        pts(members[static_cast<size_t>(k)], 0) += bx;
        pts(members[static_cast<size_t>(k)], 1) += by;
      }
      moved = true;
    }
    return moved;
  }

  // Edge e's springs at the current positions: h, the 2x2 block of their Hessian/2 (added to
  // both ends' diagonal blocks, and negated their coupling), and g, the negative half gradient
  // at end a (-g at end b).
  void edge_terms(Index e, Eigen::Matrix2d& h, Eigen::Vector2d& g) const {
    h.setZero();
    g.setZero();
    if (opt.spring_weight <= 0) return;
    const Index a = mesh.edges(e, 0), b = mesh.edges(e, 1);
    const Eigen::Vector2d d(pts(b, 0) - pts(a, 0), pts(b, 1) - pts(a, 1));
    if (has_offset_spring(mesh, e)) {
      // Offset spring: energy (B d - mu)^T Lambda (B d - mu), B = A^-1, d = p_b - p_a;
      // exactly quadratic in the positions, Hessian/2 = B^T Lambda B.
      const Eigen::Matrix2d lam =
          opt.spring_weight * (Eigen::Matrix2d() << mesh.offset_precision(e, 0), mesh.offset_precision(e, 1),
                               mesh.offset_precision(e, 2), mesh.offset_precision(e, 3)).finished();
      const Eigen::Vector2d f = to_face * d - mesh.offset_mean.row(e).transpose();
      h = to_face.transpose() * lam * to_face;
      g = to_face.transpose() * (lam * f);
    }
    // Rest lengths are face-frame lengths: energy k (|d| / s - L)² = (k / s²) (|d| - s L)²
    // with s the face's scale (1 without frame points), as the offset springs see it.
    const double k = mesh.stiffness[e] * opt.spring_weight / (face_scale * face_scale);
    const double len = d.norm();
    if (k <= 0 || len < 1e-9) return;
    const Eigen::Vector2d u = d / len;
    const double r = len - face_scale * mesh.rest_length[e];
    h += k * u * u.transpose();
    // Newton's curvature term of a stretched spring, k (r / len) (I - u u^T), is positive
    // semidefinite and speeds up motion across the spring; a compressed one's is not.
    if (r > 0) h += (k * r / len) * (Eigen::Matrix2d::Identity() - u * u.transpose());
    g += k * r * u;
  }

  // The springs `edges` alone at the current positions, per point (the other points held
  // fixed): the 2x2 Hessian/2 into diag, the negative half gradient into rhs.
  void spring_terms(const VectorXi& edges) {
    for (Index i = 0; i < P; ++i) {
      diag[i] = Eigen::Matrix2d::Identity() * opt.damping;
      rhs[i].setZero();
    }
    Eigen::Matrix2d h;
    Eigen::Vector2d g;
    for (Index q = 0; q < edges.size(); ++q) {
      const Index e = edges[q];
      const Index a = mesh.edges(e, 0), b = mesh.edges(e, 1);
      edge_terms(e, h, g);
      diag[a] += h;
      diag[b] += h;
      rhs[a] += g;
      rhs[b] -= g;
    }
  }

  // The springs' check on the data: for each end of the `outlier_edges`, the squared
  // Mahalanobis length m² = gᵀ H⁻¹ g of the step those springs alone would take (its neighbours
  // held fixed). A point whose data put it more than `spring_outlier` standard deviations from
  // where its springs want it has matched the wrong feature (a lip corner sliding onto the lip
  // crease, a lower lip caught by the upper one): its data term is muted for the rest of the
  // frame and the mesh relaxed again, so the springs place it. Worst points first, never two
  // neighbours in one round (a wrong point also strains its right neighbours). Returns whether
  // any point was muted.
  bool mute_inconsistent() {
    spring_terms(opt.outlier_edges);
    std::vector<std::pair<double, Index>> bad;
    const double limit = opt.spring_outlier * opt.spring_outlier;
    for (Index i = 0; i < P; ++i) {
      if (!checked[static_cast<size_t>(i)] || muted[static_cast<size_t>(i)]) continue;
      const Eigen::Matrix2d& h = diag[i];
      const double det = h(0, 0) * h(1, 1) - h(0, 1) * h(1, 0);
      if (!(det > 0)) continue;
      const Eigen::Vector2d step(( h(1, 1) * rhs[i](0) - h(0, 1) * rhs[i](1)) / det,
                                 (-h(1, 0) * rhs[i](0) + h(0, 0) * rhs[i](1)) / det);
      const double m2 = step.dot(h * step);
      if (m2 > limit) bad.emplace_back(m2, i);
    }
    std::sort(bad.begin(), bad.end(), [](const auto& x, const auto& y) { return x.first > y.first; });
    std::vector<char> blocked(static_cast<size_t>(P), 0);
    bool any = false;
    for (const auto& [m2, i] : bad) {
      if (blocked[static_cast<size_t>(i)]) continue;
      muted[static_cast<size_t>(i)] = 1;
      any = true;
      for (Index e = 0; e < mesh.edges.rows(); ++e) {
        if (mesh.edges(e, 0) == i) blocked[static_cast<size_t>(mesh.edges(e, 1))] = 1;
        if (mesh.edges(e, 1) == i) blocked[static_cast<size_t>(mesh.edges(e, 0))] = 1;
      }
    }
    return any;
  }

  // Point i's `reference_sides` direction (first-frame axes) in `buf`, or nullptr when it has
  // none (the whole patch, searched for in every direction).
  const Eigen::Vector2d* reference_side(Index i, Eigen::Vector2d& buf) const {
    if (opt.reference_sides.size() == 0 || (opt.reference_sides(i, 0) == 0 && opt.reference_sides(i, 1) == 0)) {
      return nullptr;
    }
    buf << opt.reference_sides(i, 0), opt.reference_sides(i, 1);
    return &buf;
  }

  // Cuts the first-frame templates at the first frame's points: every point on every level
  // (`first`) and the reference-search ones (`reference`: level 0, on their side's half), from
  // `src` seen through `warp` (the current pyramid, unwarped, when src is null).
  void cut_first_templates(const std::vector<Level>* src) {
    for (Index l = 0; l < n_levels; ++l) {
      for (Index i = 0; i < P; ++i) {
        make_template(l, i, init_pts(i, 0), init_pts(i, 1), first[static_cast<size_t>(l * P + i)], nullptr, src);
      }
    }
    reference.assign(first.begin(), first.begin() + P);
    Eigen::Vector2d buf;
    for (Index q = 0; q < opt.reference_points.size(); ++q) {
      const Index i = opt.reference_points[q];
      if (const Eigen::Vector2d* side = reference_side(i, buf)) {
        make_template(0, i, init_pts(i, 0), init_pts(i, 1), reference[static_cast<size_t>(i)], side, src);
      }
    }
  }

  // Scale of the pose the first-frame templates are seen through (1 when not warped): search
  // radii, given for the first frame, grow and shrink with the face.
  double warp_scale() const { return warped ? std::sqrt(std::abs(warp.determinant())) : 1.0; }

  // This frame's head pose from the previous frame's `frame_points` (nothing without them): the
  // similarity A for the springs, and the first-frame templates re-cut through A when it has
  // moved by more than kWarpTolerance at a patch corner since they were cut, back to the
  // uncut first-frame templates when A is that close to the identity. In-plane rotation and
  // scale of the face then change neither what a first-frame template looks like nor which
  // half of a patch a half-patch point uses; the Lucas–Kanade steps stay translations.
  void update_pose() {
    if (opt.frame_points.size() == 0) return;
    found_points(opt.frame_points, [&](Index i) { return prev_lost[static_cast<size_t>(i)] != 0; }, pose_idx);
    pose = robust_similarity(init_pts, pts, pose_idx);
    to_face = pose.inverse();
    face_scale = std::sqrt(std::abs(pose.determinant()));
    const double corner = (r + 1) * std::sqrt(2.0);
    const Eigen::Matrix2d I = Eigen::Matrix2d::Identity();
    if ((pose - I).norm() * corner <= kWarpTolerance) {
      if (warped) {
        warped = false;
        warp = I;
        warp_inv = I;
        first = first_base;
        reference = reference_base;
      }
      return;
    }
    if (warped && (pose - warp).norm() * corner <= kWarpTolerance) return;
    warped = true;
    warp = pose;
    warp_inv = to_face;
    cut_first_templates(&first_pyr);
  }

  // The `order_pairs` back in order: a pair whose lower point lies above its upper one along
  // the order axis (in the face frame) by more than the margin is moved apart onto it, each
  // point half the way.
  void enforce_order() {
    const Index K = opt.order_pairs.rows();
    if (K == 0) return;
    const Eigen::Vector2d axis = opt.order_axis.normalized();
    const Eigen::Matrix2d to_image = to_face.inverse();
    for (Index k = 0; k < K; ++k) {
      const Index up = opt.order_pairs(k, 0), lo = opt.order_pairs(k, 1);
      const Eigen::Vector2d d(pts(lo, 0) - pts(up, 0), pts(lo, 1) - pts(up, 1));
      const double s = (to_face * d).dot(axis) + opt.order_margin;
      if (!(s < 0)) continue;
      const Eigen::Vector2d half = to_image * (axis * (-0.5 * s));
      pts(lo, 0) += half(0);
      pts(lo, 1) += half(1);
      pts(up, 0) -= half(0);
      pts(up, 1) -= half(1);
    }
  }

  // Joint Gauss–Newton relaxation over levels [l_hi .. l_lo] against `tpls`; updates pts.
  Index relax(Index l_hi, Index l_lo, const std::vector<Template>& tpls) {
    const Index n = 2 * P;
    const double inv_s2 = 1.0 / (opt.intensity_sigma * opt.intensity_sigma);
    Index iterations = 0;
    for (Index l = l_hi; l >= l_lo; --l) {
      const double scale = 1.0 / static_cast<double>(Index(1) << l);
      for (Index it = 0; it < opt.max_iterations; ++it) {
        ++iterations;
        for (Index i = 0; i < P; ++i) {
          diag[i] = Eigen::Matrix2d::Identity() * opt.damping;
          rhs[i].setZero();
        }
        for (Index i = 0; i < P; ++i) {
          const Template& tpl = tpls[static_cast<size_t>(l * P + i)];
          const Match m = match(l, pts(i, 0), pts(i, 1), tpl);
          // Above the finest level a point that was reliable in the previous frame keeps its
          // full weight: a large motion lowers the coarse correlation before it is caught.
          double w = data_weight(m);
          if (l > 0 && m.textured && m.inside >= 0.5 && m.ncc > kCoarseFloor) {
            w = std::max(w, prev_weight[static_cast<size_t>(i)]);
          }
          if (muted[static_cast<size_t>(i)]) w = 0.0;
          const double c = w * inv_s2;
          if (c > 0) {
            const double cs2 = c * scale * scale;
            diag[i](0, 0) += cs2 * tpl.hxx;
            diag[i](0, 1) += cs2 * tpl.hxy;
            diag[i](1, 0) += cs2 * tpl.hxy;
            diag[i](1, 1) += cs2 * tpl.hyy;
            rhs[i](0) -= c * m.bx * scale;
            rhs[i](1) -= c * m.by * scale;
          }
        }
        if (anchors.rows() == P && opt.anchor_precision.size() == P) {
          for (Index i = 0; i < P; ++i) {
            const double lam = opt.anchor_precision[i];
            if (!(lam > 0) || std::isnan(anchors(i, 0)) || std::isnan(anchors(i, 1))) continue;
            // A spring of rest length `anchor_slack[i]` from the point to its anchor that only
            // pulls when stretched: energy lam (|d| - slack)² beyond the slack, d = a - p.
            const double slack = opt.anchor_slack.size() == P ? opt.anchor_slack[i] : 0.0;
            const Eigen::Vector2d d(anchors(i, 0) - pts(i, 0), anchors(i, 1) - pts(i, 1));
            const double len = d.norm();
            const double over = len - slack;
            if (slack <= 0) {
              diag[i] += lam * Eigen::Matrix2d::Identity();
              rhs[i] += lam * d;
            } else if (over > 0) {
              const Eigen::Vector2d u = d / len;
              diag[i] += lam * (u * u.transpose()) + (lam * over / len) * (Eigen::Matrix2d::Identity() - u * u.transpose());
              rhs[i] += lam * over * u;
            }
          }
        }
        for (Index e = 0; e < mesh.edges.rows(); ++e) {
          const Index a = mesh.edges(e, 0), b = mesh.edges(e, 1);
          Eigen::Vector2d g;
          edge_terms(e, coupling[e], g);
          diag[a] += coupling[e];
          diag[b] += coupling[e];
          coupling[e] = -coupling[e];
          rhs[a] += g;
          rhs[b] -= g;
        }
        solve();
        double max_step = 0;
        for (Index v = 0; v < n; ++v) {
          // Trust region: at most 2 level pixels per iteration, so a bad linearisation of one
          // patch cannot throw a point across the face.
          const double limit = 2.0 / scale;
          double d = delta[v / 2](v % 2);
          if (!std::isfinite(d)) d = 0;
          d = std::clamp(d, -limit, limit);
          pts(v / 2, v % 2) += d;
          max_step = std::max(max_step, std::abs(d) * scale);
        }
        enforce_order();
        // Coarse levels only need to land within the next level's reach.
        if (max_step < (l > l_lo ? std::max(opt.tolerance, 0.1) : opt.tolerance)) break;
      }
    }
    return iterations;
  }
};

namespace {

void check_options(const TrackerOptions& o) {
  if (o.patch_radius < 1 || o.patch_radius > 64) {
    fail_argument("options.patch_radius must be in [1, 64] pixels, got ", o.patch_radius);
  }
  if (o.levels < 1 || o.levels > 8) fail_argument("options.levels must be in [1, 8], got ", o.levels);
  if (o.max_iterations < 1) {
    fail_argument("options.max_iterations must be >= 1, got ", o.max_iterations);
  }
  auto positive = [](double v, const char* name) {
    if (!(std::isfinite(v) && v > 0)) fail_argument("options.", name, " must be > 0, got ", v);
  };
  positive(o.tolerance, "tolerance");
  positive(o.intensity_sigma, "intensity_sigma");
  positive(o.drift_tolerance, "drift_tolerance");
  positive(o.damping, "damping");
  if (!(std::isfinite(o.search_radius) && o.search_radius >= 0 && o.search_radius <= 64)) {
    fail_argument("options.search_radius must be in [0, 64] pixels, got ", o.search_radius);
  }
  if (!(std::isfinite(o.group_search_radius) && o.group_search_radius >= 0 && o.group_search_radius <= 64)) {
    fail_argument("options.group_search_radius must be in [0, 64] pixels, got ", o.group_search_radius);
  }
  if (!(std::isfinite(o.reference_search_radius) && o.reference_search_radius >= 0 &&
        o.reference_search_radius <= 64)) {
    fail_argument("options.reference_search_radius must be in [0, 64] pixels, got ", o.reference_search_radius);
  }
  if (!(o.reference_search_ncc >= -1 && o.reference_search_ncc <= 1)) {
    fail_argument("options.reference_search_ncc must be a correlation in [-1, 1], got ", o.reference_search_ncc);
  }
  if (!(std::isfinite(o.spring_outlier) && o.spring_outlier >= 0)) {
    fail_argument("options.spring_outlier must be a number of standard deviations >= 0 (0: off), got ",
                  o.spring_outlier);
  }
  if (!(std::isfinite(o.spring_weight) && o.spring_weight >= 0)) {
    fail_argument("options.spring_weight must be finite and >= 0, got ", o.spring_weight);
  }
  if (!(o.ncc_floor >= -1 && o.ncc_floor < o.ncc_full && o.ncc_full <= 1)) {
    fail_argument("options need -1 <= ncc_floor < ncc_full <= 1, got ncc_floor = ", o.ncc_floor,
                  ", ncc_full = ", o.ncc_full);
  }
  if (!(o.lost_confidence >= 0 && o.lost_confidence <= 1)) {
    fail_argument("options.lost_confidence must be in [0, 1], got ", o.lost_confidence);
  }
}

}  // namespace

SpringMeshTracker::SpringMeshTracker(const GreyImage& first, const MatrixRef& points,
                                     const SpringMesh& mesh, const TrackerOptions& options)
    : impl_(std::make_unique<Impl>()) {
  check_grey_image(first, "first frame");
  check_points(points, "points");
  if (points.rows() < 3) {
    fail_argument("points must hold at least 3 landmarks for a spring mesh, got ", points.rows());
  }
  check_options(options);
  for (Index i = 0; i < points.rows(); ++i) {
    const double x = points(i, 0), y = points(i, 1);
    if (x < 0 || y < 0 || x > static_cast<double>(first.width - 1) ||
        y > static_cast<double>(first.height - 1)) {
      fail_argument("points row ", i, " = (", x, ", ", y, ") is outside the ", first.width, " x ",
                    first.height, " first frame; initial points must lie inside the image "
                    "(x in [0, ", first.width - 1, "], y in [0, ", first.height - 1, "])");
    }
  }
  check_mesh(mesh, points.rows());
  check_frame_points(options.frame_points, points.rows(), "options.frame_points");
  for (Index k = 0; k < options.order_pairs.rows(); ++k) {
    const Index up = options.order_pairs(k, 0), lo = options.order_pairs(k, 1);
    if (up < 0 || lo < 0 || up >= points.rows() || lo >= points.rows() || up == lo) {
      fail_argument("options.order_pairs row ", k, " = (", up, ", ", lo, ") must be two different point "
                    "indices in [0, ", points.rows() - 1, "]");
    }
  }
  if (!(std::isfinite(options.order_margin) && options.order_margin >= 0)) {
    fail_argument("options.order_margin must be a finite number of pixels >= 0, got ", options.order_margin);
  }
  if (options.order_pairs.rows() != 0 &&
      !(options.order_axis.allFinite() && options.order_axis.norm() > 0)) {
    fail_argument("options.order_axis must be a finite non-zero direction, got (", options.order_axis(0), ", ",
                  options.order_axis(1), ")");
  }
  if (options.anchor_slack.size() != 0 &&
      (options.anchor_slack.size() != points.rows() || !options.anchor_slack.allFinite() ||
       options.anchor_slack.minCoeff() < 0)) {
    fail_argument("options.anchor_slack must hold ", points.rows(), " finite numbers of pixels >= 0 (one per "
                  "point) or be empty, got ", options.anchor_slack.size(), " values");
  }
  if (options.anchor_precision.size() != 0 &&
      (options.anchor_precision.size() != points.rows() || !options.anchor_precision.allFinite() ||
       options.anchor_precision.minCoeff() < 0)) {
    fail_argument("options.anchor_precision must hold ", points.rows(), " finite precisions >= 0 (1/px², one per "
                  "point; 0: no anchor) or be empty, got ", options.anchor_precision.size(), " values");
  }
  if (options.reference_sides.size() != 0 &&
      (options.reference_sides.rows() != points.rows() || options.reference_sides.cols() != 2 ||
       !options.reference_sides.allFinite())) {
    fail_argument("options.reference_sides must be ", points.rows(), " by 2 finite directions (one per point; a zero row: "
                  "the whole patch, searched for in every direction) or empty, got ", options.reference_sides.rows(),
                  " by ", options.reference_sides.cols());
  }
  for (Index q = 0; q < options.reference_points.size(); ++q) {
    const Index i = options.reference_points[q];
    if (i < 0 || i >= points.rows()) {
      fail_argument("options.reference_points[", q, "] = ", i, " is not a point index (0 to ", points.rows() - 1,
                    "); pass indices of the points to search for against their first-frame templates");
    }
  }
  if (options.search_groups.size() != 0) {
    if (options.search_groups.size() != points.rows() || options.search_groups.minCoeff() < -1) {
      fail_argument("options.search_groups must hold one group id per point (", points.rows(),
                    " of them; -1: in no group) or be empty, got ", options.search_groups.size(),
                    " ids with minimum ", options.search_groups.minCoeff());
    }
  }
  for (Index q = 0; q < options.outlier_edges.size(); ++q) {
    if (options.outlier_edges[q] < 0 || options.outlier_edges[q] >= mesh.edges.rows()) {
      fail_argument("options.outlier_edges[", q, "] = ", options.outlier_edges[q],
                    " is not an edge index; indices must be in [0, ", mesh.edges.rows() - 1, "]");
    }
  }
  if (options.patch_sides.size() != 0) {
    if (options.patch_sides.rows() != points.rows() || options.patch_sides.cols() != 2) {
      fail_argument("options.patch_sides must have shape (P, 2) = (", points.rows(),
                    ", 2), one direction per point, or be empty; got ",
                    shape_of(options.patch_sides));
    }
    require_finite(options.patch_sides, "options.patch_sides");
  }
  Impl& s = *impl_;
  s.sides = options.patch_sides;
  s.opt = options;
  s.mesh = mesh;
  s.P = points.rows();
  s.width = first.width;
  s.height = first.height;
  s.r = static_cast<int>(options.patch_radius);
  s.n_pix = (2 * s.r + 1) * (2 * s.r + 1);
  s.n_pad = (s.n_pix + kLanes - 1) / kLanes * kLanes;
  s.pts = points;
  s.init_pts = points;
  // Use a level only if it is at least two patches wide and high.
  s.n_levels = 1;
  while (s.n_levels < options.levels &&
         std::min(first.width, first.height) >> s.n_levels >= 2 * (2 * s.r + 3)) {
    ++s.n_levels;
  }
  s.patch.assign(static_cast<size_t>(s.n_pad), 0.0f);
  s.big.resize(static_cast<size_t>((2 * s.r + 3) * (2 * s.r + 3)));
  for (auto* v : {&s.rhs, &s.delta, &s.res, &s.z, &s.dir, &s.adir}) v->resize(static_cast<size_t>(s.P));
  s.diag.resize(static_cast<size_t>(s.P));
  s.inv.resize(static_cast<size_t>(s.P));
  s.coupling.resize(static_cast<size_t>(mesh.edges.rows()));
  s.build_pyramid(first);
  s.first.resize(static_cast<size_t>(s.n_levels * s.P));
  s.cut_first_templates(nullptr);
  s.current = s.first;
  if (options.frame_points.size() != 0) {
    // The first frame's pyramid outlives the caller's buffer: first-frame templates are re-cut
    // from it as the head turns and scales.
    s.first_base = s.first;
    s.reference_base = s.reference;
    s.first_pyr.resize(s.pyr.size());
    for (size_t l = 0; l < s.pyr.size(); ++l) {
      const Level& src = s.pyr[l];
      Level& dst = s.first_pyr[l];
      dst.width = src.width;
      dst.height = src.height;
      dst.stride = src.width;
      dst.owned.resize(static_cast<size_t>(src.width * src.height));
      for (Index y = 0; y < src.height; ++y) {
        std::copy(src.data + y * src.stride, src.data + y * src.stride + src.width,
                  dst.owned.begin() + y * src.width);
      }
      dst.data = dst.owned.data();
    }
  }
  s.prev_weight.assign(static_cast<size_t>(s.P), 1.0);
  s.prev_lost.assign(static_cast<size_t>(s.P), 0);
  s.muted.assign(static_cast<size_t>(s.P), 0);
  s.checked.assign(static_cast<size_t>(s.P), 0);
  for (Index q = 0; q < options.outlier_edges.size(); ++q) {
    const Index e = options.outlier_edges[q];
    s.checked[static_cast<size_t>(mesh.edges(e, 0))] = 1;
    s.checked[static_cast<size_t>(mesh.edges(e, 1))] = 1;
  }
}

SpringMeshTracker::~SpringMeshTracker() = default;
SpringMeshTracker::SpringMeshTracker(SpringMeshTracker&&) noexcept = default;
SpringMeshTracker& SpringMeshTracker::operator=(SpringMeshTracker&&) noexcept = default;

TrackerFrame SpringMeshTracker::track(const GreyImage& frame, const MatrixRef& anchors) {
  Impl& s = *impl_;
  if (anchors.rows() != s.P || anchors.cols() != 2) {
    fail_argument("anchors must have shape (", s.P, ", 2), one (x, y) row per tracked point (NaN: none), got ",
                  shape_of(anchors));
  }
  for (Index i = 0; i < s.P; ++i) {
    if (std::isinf(anchors(i, 0)) || std::isinf(anchors(i, 1))) {
      fail_argument("anchors row ", i, " is infinite; give a position or NaN for no anchor");
    }
  }
  s.anchors = anchors;
  try {
    TrackerFrame out = track(frame);
    s.anchors.resize(0, 2);
    return out;
  } catch (...) {
    s.anchors.resize(0, 2);
    throw;
  }
}

TrackerFrame SpringMeshTracker::track(const GreyImage& frame) {
  check_grey_image(frame, "frame");
  Impl& s = *impl_;
  if (frame.width != s.width || frame.height != s.height) {
    fail_argument("frame is ", frame.width, " x ", frame.height, " but the tracker was started on a ",
                  s.width, " x ", s.height, " frame; every frame of a sequence must have one size");
  }
  s.build_pyramid(frame);
  s.update_pose();
  TrackerFrame out;
  // Stage A: coarse to fine against the current templates.
  out.iterations = s.relax(s.n_levels - 1, 0, s.current);
  // Half-patch points that stage A left on a poor match are searched for, and the mesh is
  // relaxed again from where they were found.
  if (s.opt.group_search_radius > 0 && s.group_search()) {
    out.iterations += s.relax(0, 0, s.current);
  }
  if (s.opt.search_radius > 0 && s.search()) {
    out.iterations += s.relax(0, 0, s.current);
  }
  // Points found again against their first-frame templates go straight to stage B, which
  // refines them against those templates (relaxing against the current templates first would
  // pull them back toward where those templates had followed the contour).
  if (s.opt.reference_search_radius > 0) s.reference_search();
  // Points whose data disagree with their offset springs are handed to the springs.
  std::fill(s.muted.begin(), s.muted.end(), 0);
  for (int round = 0; round < 2 && s.opt.spring_outlier > 0 && s.mute_inconsistent(); ++round) {
    out.iterations += s.relax(0, 0, s.current);
  }
  const RowMatrixXd stage_a = s.pts;
  // Stage B: drift correction against the first-frame templates, at the finest level.
  out.iterations += s.relax(0, 0, s.first);
  out.points.resize(s.P, 2);
  out.confidence.resize(s.P);
  out.lost.resize(s.P);
  Template fresh;
  for (Index i = 0; i < s.P; ++i) {
    const Match mb = s.match(0, s.pts(i, 0), s.pts(i, 1), s.first[static_cast<size_t>(i)]);
    const double drift = (s.pts.row(i) - stage_a.row(i)).norm();
    const bool accept = mb.textured && mb.inside >= 1.0 && drift <= s.opt.drift_tolerance &&
                        mb.ncc >= s.opt.ncc_full;
    double conf;
    double inside;
    if (accept) {
      conf = mb.ncc;
      inside = mb.inside;
      for (Index l = 0; l < s.n_levels; ++l) {
        s.make_template(l, i, s.pts(i, 0), s.pts(i, 1), s.current[static_cast<size_t>(l * s.P + i)]);
      }
    } else {
      // Keep the current-template answer; its confidence is still judged against the
      // first-frame template, so a current template that drifted cannot vouch for itself.
      s.pts.row(i) = stage_a.row(i);
      const Match ma = s.match(0, s.pts(i, 0), s.pts(i, 1), s.first[static_cast<size_t>(i)]);
      conf = ma.textured ? ma.ncc : 0.0;
      inside = ma.inside;
    }
    conf = std::clamp(conf, 0.0, 1.0);
    const double x = s.pts(i, 0), y = s.pts(i, 1);
    const bool outside = x < 0 || y < 0 || x > static_cast<double>(s.width - 1) ||
                         y > static_cast<double>(s.height - 1) || inside < 0.5;
    out.confidence[i] = outside ? 0.0 : conf;
    s.prev_weight[static_cast<size_t>(i)] =
        std::clamp((out.confidence[i] - s.opt.ncc_floor) / (s.opt.ncc_full - s.opt.ncc_floor), 0.0, 1.0);
    out.lost[i] = outside || conf < s.opt.lost_confidence;
    s.prev_lost[static_cast<size_t>(i)] = out.lost[i] ? 1 : 0;
  }
  // Points that kept their stage-A answer beside others that took stage B's may be out of order.
  s.enforce_order();
  out.points = s.pts;
  return out;
}

void SpringMeshTracker::relocate(const MatrixRef& points) {
  Impl& s = *impl_;
  if (points.rows() != s.P || points.cols() != 2) {
    fail_argument("points must have shape (", s.P, ", 2), one (x, y) row per tracked point, got ",
                  shape_of(points), "; pass every point of the mesh at its new position");
  }
  require_finite(points, "points");
  s.pts = points;
  std::fill(s.prev_weight.begin(), s.prev_weight.end(), 1.0);
  std::fill(s.prev_lost.begin(), s.prev_lost.end(), 0);
  std::fill(s.muted.begin(), s.muted.end(), 0);
  // The head pose of the new points (all of them found), and the first-frame templates seen
  // through it; the current templates start from those.
  s.update_pose();
  s.current = s.first;
}

const RowMatrixXd& SpringMeshTracker::points() const { return impl_->pts; }
Index SpringMeshTracker::n_points() const { return impl_->P; }
Index SpringMeshTracker::width() const { return impl_->width; }
Index SpringMeshTracker::height() const { return impl_->height; }
Index SpringMeshTracker::levels() const { return impl_->n_levels; }
const SpringMesh& SpringMeshTracker::mesh() const { return impl_->mesh; }
const TrackerOptions& SpringMeshTracker::options() const { return impl_->opt; }

}  // namespace voicepuppet
