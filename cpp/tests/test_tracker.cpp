// Tests of the spring-mesh SSD tracker against planted truth: analytic textures shifted by known
// sub-pixel offsets, closed-form spring statistics, and counting identities of triangulations.
#include <doctest/doctest.h>

#include "voicepuppet/tracker.hpp"

#include <Eigen/LU>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <random>
#include <set>
#include <utility>
#include <vector>

using namespace voicepuppet;

namespace {

// A smooth, non-periodic texture: a sum of sinusoids with fixed "random" frequencies and phases.
struct Texture {
  std::vector<std::array<double, 4>> waves;  // kx, ky, phase, amplitude
  explicit Texture(unsigned seed) {
    std::mt19937 rng(seed);
    // Wavenumbers log-uniform in [0.04, 0.5] rad/px, like the 1/f spectrum of natural images.
    std::uniform_real_distribution<double> logk(std::log(0.04), std::log(0.5)),
        angle(0, 6.283185307179586);
    for (int k = 0; k < 12; ++k) {
      const double kk = std::exp(logk(rng)), a = angle(rng);
      waves.push_back({kk * std::cos(a), kk * std::sin(a), angle(rng), 9.0});
    }
  }
  double operator()(double x, double y) const {
    double v = 128;
    for (const auto& w : waves) v += w[3] * std::sin(w[0] * x + w[1] * y + w[2]);
    return v;
  }
};

struct Frame {
  std::vector<std::uint8_t> pix;
  Index w, h;
  GreyImage view() const { return GreyImage{pix.data(), w, h, w}; }
};

// Renders texture(x - dx, y - dy) * gain + bias: content moved by (+dx, +dy).
Frame render(const Texture& tex, Index w, Index h, double dx, double dy, double gain = 1,
             double bias = 0) {
  Frame f{std::vector<std::uint8_t>(static_cast<size_t>(w * h)), w, h};
  for (Index y = 0; y < h; ++y) {
    for (Index x = 0; x < w; ++x) {
      const double v = gain * tex(double(x) - dx, double(y) - dy) + bias;
      f.pix[static_cast<size_t>(y * w + x)] =
          static_cast<std::uint8_t>(std::lround(std::clamp(v, 0.0, 255.0)));
    }
  }
  return f;
}

RowMatrixXd grid_points(int nx, int ny, double x0, double y0, double step) {
  RowMatrixXd p(nx * ny, 2);
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      p(j * nx + i, 0) = x0 + i * step + 0.3 * j;  // slight shear: general position
      p(j * nx + i, 1) = y0 + j * step + 0.2 * i;
    }
  }
  return p;
}

// The right triangle with sides 3, 4, 5 and its three edges.
RowMatrixXd triangle_3_4_5() {
  RowMatrixXd p(3, 2);
  p << 0, 0, 3, 0, 0, 4;
  return p;
}

EdgeMatrix triangle_edges() {
  EdgeMatrix e(3, 2);
  e << 0, 1, 0, 2, 1, 2;
  return e;
}

}  // namespace

TEST_CASE("delaunay_edges: square with its centre gives 4 sides and 4 spokes") {
  RowMatrixXd p(5, 2);
  p << 0, 0, 10, 0, 10, 10, 0, 10, 5, 5;
  const EdgeMatrix e = delaunay_edges(p);
  std::set<std::pair<Index, Index>> got;
  for (Index k = 0; k < e.rows(); ++k) got.insert({e(k, 0), e(k, 1)});
  const std::set<std::pair<Index, Index>> want = {{0, 1}, {1, 2}, {2, 3}, {0, 3},
                                                  {0, 4}, {1, 4}, {2, 4}, {3, 4}};
  CHECK(got == want);
}

TEST_CASE("delaunay_edges: random points satisfy E = 3n - 3 - h and the empty-circle property") {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0, 640);
  for (int trial = 0; trial < 5; ++trial) {
    const Index n = 26 + 10 * trial;
    RowMatrixXd p(n, 2);
    for (Index i = 0; i < n; ++i) p.row(i) << u(rng), u(rng);
    const EdgeMatrix e = delaunay_edges(p);
    // Hull size by gift wrapping (points in general position).
    Index h = 0;
    {
      Index start = 0;
      for (Index i = 1; i < n; ++i) if (p(i, 0) < p(start, 0)) start = i;
      Index cur = start;
      do {
        ++h;
        Index next = (cur + 1) % n;
        for (Index i = 0; i < n; ++i) {
          const double cr = (p(next, 0) - p(cur, 0)) * (p(i, 1) - p(cur, 1)) -
                            (p(next, 1) - p(cur, 1)) * (p(i, 0) - p(cur, 0));
          if (cr < 0) next = i;
        }
        cur = next;
      } while (cur != start && h <= n);
    }
    CHECK(e.rows() == 3 * n - 3 - h);
    // Every edge has an empty circle through its endpoints (the edge's Delaunay property):
    // test via the triangles formed with common neighbours.
    std::set<std::pair<Index, Index>> es;
    for (Index k = 0; k < e.rows(); ++k) es.insert({e(k, 0), e(k, 1)});
    auto has = [&](Index a, Index b) { return es.count({std::min(a, b), std::max(a, b)}) > 0; };
    for (const auto& [a, b] : es) {
      for (Index c = 0; c < n; ++c) {
        if (c == a || c == b || !has(a, c) || !has(b, c)) continue;
        // Triangle (a, b, c) of the mesh: no point strictly inside its circumcircle, unless the
        // three edges do not bound a face (a point inside the triangle itself).
        const double ax = p(a, 0), ay = p(a, 1), bx = p(b, 0), by = p(b, 1), cx = p(c, 0), cy = p(c, 1);
        const double d = 2 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by));
        const double ux = ((ax * ax + ay * ay) * (by - cy) + (bx * bx + by * by) * (cy - ay) +
                           (cx * cx + cy * cy) * (ay - by)) / d;
        const double uy = ((ax * ax + ay * ay) * (cx - bx) + (bx * bx + by * by) * (ax - cx) +
                           (cx * cx + cy * cy) * (bx - ax)) / d;
        const double r2 = (ax - ux) * (ax - ux) + (ay - uy) * (ay - uy);
        bool face = true;
        for (Index q = 0; q < n && face; ++q) {
          if (q == a || q == b || q == c) continue;
          const double s1 = (bx - ax) * (p(q, 1) - ay) - (by - ay) * (p(q, 0) - ax);
          const double s2 = (cx - bx) * (p(q, 1) - by) - (cy - by) * (p(q, 0) - bx);
          const double s3 = (ax - cx) * (p(q, 1) - cy) - (ay - cy) * (p(q, 0) - cx);
          if ((s1 > 0 && s2 > 0 && s3 > 0) || (s1 < 0 && s2 < 0 && s3 < 0)) face = false;
        }
        if (!face) continue;
        for (Index q = 0; q < n; ++q) {
          if (q == a || q == b || q == c) continue;
          const double d2 = (p(q, 0) - ux) * (p(q, 0) - ux) + (p(q, 1) - uy) * (p(q, 1) - uy);
          CHECK(d2 >= r2 * (1 - 1e-9));
        }
      }
    }
  }
}

TEST_CASE("delaunay_edges: bad input is refused with a reason") {
  RowMatrixXd two(2, 2);
  two << 0, 0, 1, 1;
  CHECK_THROWS_AS(delaunay_edges(two), std::invalid_argument);
  RowMatrixXd line(4, 2);
  line << 0, 0, 1, 1, 2, 2, 3, 3;
  CHECK_THROWS_WITH_AS(delaunay_edges(line), doctest::Contains("one line"), std::invalid_argument);
  RowMatrixXd dup(4, 2);
  dup << 0, 0, 5, 0, 0, 5, 5, 0;
  CHECK_THROWS_WITH_AS(delaunay_edges(dup), doctest::Contains("coincide"), std::invalid_argument);
}

TEST_CASE("springs_from_points and estimate_springs: closed-form lengths, means and variances") {
  const RowMatrixXd p = triangle_3_4_5();
  const EdgeMatrix e = triangle_edges();
  const SpringMesh m = springs_from_points(p, e, 0.1);
  CHECK(m.rest_length[0] == doctest::Approx(3));
  CHECK(m.rest_length[2] == doctest::Approx(5));
  CHECK(m.stiffness[2] == doctest::Approx(1.0 / 0.25));
  // A floor of 0.4 px on the std: the 3 px spring (0.3 px) is floored, the 5 px one is not.
  const SpringMesh floored = springs_from_points(p, e, 0.1, 0.4);
  CHECK(floored.stiffness[0] == doctest::Approx(1.0 / 0.16));
  CHECK(floored.stiffness[2] == doctest::Approx(1.0 / 0.25));
  CHECK_THROWS_WITH_AS(springs_from_points(p, e, 0.1, -1.0), doctest::Contains("min_sigma"),
                       std::invalid_argument);
  // Frames scale the triangle by 1, 2, 3 and a 4th frame (scale 100) has point 2 lost.
  RowMatrixXd tracks(4, 6);
  RowMatrixXb lost = RowMatrixXb::Zero(4, 3);
  for (int t = 0; t < 4; ++t) {
    const double s = t < 3 ? t + 1 : 100;
    tracks.row(t) << 0, 0, 3 * s, 0, 0, 4 * s;
  }
  lost(3, 2) = true;
  const SpringMesh r = estimate_springs(tracks, lost, m, 0.5);
  // Edge 0 sees 3, 6, 9 and 300: median 7.5, MAD 3, so 300 lies beyond 3 robust sigmas
  // (3 * 1.4826 * 3 = 13.3) and is left out: mean 6, variance 9.
  CHECK(r.rest_length[0] == doctest::Approx(6));
  CHECK(r.stiffness[0] == doctest::Approx(1.0 / 9));
  CHECK(r.rest_length[1] == doctest::Approx(8));   // frames 0..2 only: 4, 8, 12
  CHECK(r.stiffness[1] == doctest::Approx(1.0 / 16));  // sample variance of 4, 8, 12
  CHECK(r.rest_length[2] == doctest::Approx(10));
  // Constant distances hit the variance floor.
  RowMatrixXd still(3, 6);
  for (int t = 0; t < 3; ++t) still.row(t) << 0, 0, 3, 0, 0, 4;
  const SpringMesh f = estimate_springs(still, RowMatrixXb::Zero(3, 3), m, 0.5);
  CHECK(f.stiffness[0] == doctest::Approx(4.0));
  CHECK_THROWS_AS(estimate_springs(still, RowMatrixXb::Zero(2, 3), m, 0.5), std::invalid_argument);
}

TEST_CASE("face_similarity and offset springs: planted rotations, scales and offset statistics") {
  // Four frame points rotated by 0.1 rad, scaled by 1.2 and moved: recovered exactly.
  RowMatrixXd from(4, 2), to(4, 2);
  from << 0, 0, 10, 0, 10, 5, -3, 8;
  const double c = 1.2 * std::cos(0.1), sn = 1.2 * std::sin(0.1);
  for (Index i = 0; i < 4; ++i) {
    to.row(i) << c * from(i, 0) - sn * from(i, 1) + 7, sn * from(i, 0) + c * from(i, 1) - 2;
  }
  VectorXi idx(4);
  idx << 0, 1, 2, 3;
  const Eigen::Matrix2d A = face_similarity(from, to, idx);
  CHECK(A(0, 0) == doctest::Approx(c));
  CHECK(A(1, 0) == doctest::Approx(sn));
  CHECK(A(0, 1) == doctest::Approx(-sn));
  CHECK(face_similarity(from, to, VectorXi()).isIdentity());
  // A pass of T frames: points 0..2 are a rigid triangle under a known similarity A_t; point 3
  // hangs off point 0 by a face-frame offset f_t drawn from N(mu, Sigma), so edge (0, 3) seen in
  // the image is A_t f_t. The offset spring must find mu and Sigma^-1 of the drawn f_t
  // (the face frame undone), and switch the edge's length spring off.
  std::mt19937 rng(3);
  std::normal_distribution<double> g(0, 1);
  const int T = 400;
  RowMatrixXd base(4, 2);
  base << 0, 0, 20, 0, 5, 15, 2, 10;
  RowMatrixXd tracks(T, 8);
  std::vector<Eigen::Vector2d> drawn;
  for (int t = 0; t < T; ++t) {
    const double ang = t == 0 ? 0.0 : 0.05 * g(rng), sc = t == 0 ? 1.0 : 1 + 0.03 * g(rng);
    Eigen::Matrix2d At;
    At << sc * std::cos(ang), -sc * std::sin(ang), sc * std::sin(ang), sc * std::cos(ang);
    const Eigen::Vector2d shift(3 * g(rng), 3 * g(rng));
    // f = mu + L z with Sigma = L L^T = [[0.25, 0.3], [0.3, 4.0]]
    const double z1 = g(rng), z2 = g(rng);
    Eigen::Vector2d f(2 + 0.5 * z1, 10 + 0.6 * z1 + std::sqrt(4.0 - 0.36) * z2);
    if (t == 0) f << 2, 10;
    drawn.push_back(f);
    for (Index i = 0; i < 3; ++i) {
      const Eigen::Vector2d q = At * base.row(i).transpose() + shift;
      tracks(t, 2 * i) = q[0];
      tracks(t, 2 * i + 1) = q[1];
    }
    const Eigen::Vector2d q3 = At * (base.row(0).transpose() + f) + shift;
    tracks(t, 6) = q3[0];
    tracks(t, 7) = q3[1];
  }
  EdgeMatrix e(4, 2);
  e << 0, 1, 0, 2, 0, 3, 1, 2;
  SpringMesh m = springs_from_points(base, e);
  m.offset_precision = RowMatrixXd::Zero(4, 4);
  m.offset_mean = RowMatrixXd::Zero(4, 2);
  m.offset_precision.row(2) << 1, 0, 0, 1;
  VectorXi frame(3);
  frame << 0, 1, 2;
  const SpringMesh r = estimate_springs(tracks, RowMatrixXb::Zero(T, 4), m, 0.1, frame);
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& f : drawn) mean += f;
  mean /= T;
  Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
  for (const auto& f : drawn) cov += (f - mean) * (f - mean).transpose();
  cov /= T - 1;
  const Eigen::Matrix2d prec = cov.inverse();
  CHECK(r.offset_mean(2, 0) == doctest::Approx(mean[0]).epsilon(1e-9));
  CHECK(r.offset_mean(2, 1) == doctest::Approx(mean[1]).epsilon(1e-9));
  CHECK(r.offset_precision(2, 0) == doctest::Approx(prec(0, 0)).epsilon(1e-9));
  CHECK(r.offset_precision(2, 1) == doctest::Approx(prec(0, 1)).epsilon(1e-9));
  CHECK(r.offset_precision(2, 2) == doctest::Approx(prec(1, 0)).epsilon(1e-9));
  CHECK(r.offset_precision(2, 3) == doctest::Approx(prec(1, 1)).epsilon(1e-9));
  CHECK(r.stiffness[2] == 0.0);
  CHECK(r.stiffness[0] > 0);  // length springs elsewhere as before
  CHECK(r.offset_precision.row(0).isZero());
  // The eigenvalue floor: a constant offset gets precision 1/min_sigma^2 in every direction.
  RowMatrixXd still(3, 8);
  for (int t = 0; t < 3; ++t) still.row(t) << 0, 0, 20, 0, 5, 15, 2, 10;
  const SpringMesh f = estimate_springs(still, RowMatrixXb::Zero(3, 4), m, 0.5, frame);
  CHECK(f.offset_precision(2, 0) == doctest::Approx(4.0));
  CHECK(f.offset_precision(2, 3) == doctest::Approx(4.0));
  CHECK(f.offset_precision(2, 1) == doctest::Approx(0.0));
  // Bad offset springs are refused with a reason.
  SpringMesh bad = m;
  bad.offset_precision.row(2) << 1, 2, 2, 1;  // indefinite
  CHECK_THROWS_WITH_AS(estimate_springs(still, RowMatrixXb::Zero(3, 4), bad, 0.5),
                       doctest::Contains("positive semidefinite"), std::invalid_argument);
  bad = m;
  bad.offset_mean.resize(0, 0);
  CHECK_THROWS_WITH_AS(estimate_springs(still, RowMatrixXb::Zero(3, 4), bad, 0.5),
                       doctest::Contains("together"), std::invalid_argument);
  VectorXi one(1);
  one << 0;
  CHECK_THROWS_WITH_AS(estimate_springs(still, RowMatrixXb::Zero(3, 4), m, 0.5, one),
                       doctest::Contains("at least 2"), std::invalid_argument);
}

// A w by h frame of value(x, y), rounded and clipped to 8 bits.
template <class F>
Frame render_with(Index w, Index h, F value) {
  Frame f{std::vector<std::uint8_t>(static_cast<size_t>(w * h)), w, h};
  for (Index y = 0; y < h; ++y) {
    for (Index x = 0; x < w; ++x) {
      f.pix[static_cast<size_t>(y * w + x)] =
          static_cast<std::uint8_t>(std::lround(std::clamp(value(double(x), double(y)), 0.0, 255.0)));
    }
  }
  return f;
}

// Point 1 sits on horizontal stripes (texture in y only: the aperture problem of a lip contour),
// points 0 and 2 on a full texture above; the whole image moves by (dx, dy).
Frame render_stripes(const Texture& tex, double dx, double dy) {
  return render_with(120, 110, [&](double x, double y) {
    const double u = x - dx, v = y - dy;
    return v < 50 ? tex(u, v) : 128 + 40 * std::sin(0.45 * v) + 20 * std::sin(0.9 * v + 1);
  });
}

TEST_CASE("tracker: an offset spring stops a point sliding along its contour") {
  const Texture tex(11);
  // Point 1 hangs below point 0 on one spring, across the stripes: a length spring says
  // nothing about a slide along them (first order), an offset spring does.
  RowMatrixXd p(3, 2);
  p << 40, 25, 40, 72, 80, 25;
  EdgeMatrix e(2, 2);
  e << 0, 1, 0, 2;
  TrackerOptions o;
  o.levels = 1;
  o.frame_points.resize(2);
  o.frame_points << 0, 2;
  const SpringMesh length_only = springs_from_points(p, e, 0.05);
  // An offset spring on the edge to the striped point: stiff (0.3 px) along x, soft (3 px) along y.
  SpringMesh offsets = length_only;
  offsets.offset_precision = RowMatrixXd::Zero(2, 4);
  offsets.offset_mean = RowMatrixXd::Zero(2, 2);
  for (const Index k : {Index(0)}) {
    offsets.offset_precision.row(k) << 1 / 0.09, 0, 0, 1 / 9.0;
    offsets.offset_mean.row(k) = p.row(e(k, 1)) - p.row(e(k, 0));
    offsets.stiffness[k] = 0;
  }
  const Frame f0 = render_stripes(tex, 0, 0);
  SpringMeshTracker a(f0.view(), p, length_only, o), b(f0.view(), p, offsets, o);
  double dx = 0, dy = 0;
  for (int t = 1; t <= 12; ++t) {
    dx = 0.6 * t;
    dy = 0.3 * t;
    const Frame f = render_stripes(tex, dx, dy);
    a.track(f.view());
    b.track(f.view());
  }
  const double err_length = std::hypot(a.points()(1, 0) - (40 + dx), a.points()(1, 1) - (72 + dy));
  const double err_offset = std::hypot(b.points()(1, 0) - (40 + dx), b.points()(1, 1) - (72 + dy));
  MESSAGE("striped point: error " << err_length << " px with length springs, " << err_offset
                                  << " px with offset springs");
  CHECK(err_offset < 0.2);
  CHECK(err_length > 1.0);  // the length spring lets it lag behind along the stripes (1.4 px)
  for (const Index i : {Index(0), Index(2)}) {
    CHECK(std::hypot(b.points()(i, 0) - (p(i, 0) + dx), b.points()(i, 1) - (p(i, 1) + dy)) < 0.1);
  }
}

// A mouth seen edge-on: a textured lower lip, `band` px tall, hangs below the line y = y0 + s
// and moves down with s over a static chin; above the line is a different texture in frame 0
// (closed lips) and a flat dark cavity afterwards (an open mouth).
Frame render_mouth(const Texture& lip, const Texture& closed, const Texture& chin, double y0,
                   double s, bool open) {
  const Index w = 200, h = 160;
  const double band = 8;
  Frame f{std::vector<std::uint8_t>(static_cast<size_t>(w * h)), w, h};
  for (Index y = 0; y < h; ++y) {
    for (Index x = 0; x < w; ++x) {
      const double yy = static_cast<double>(y) - (y0 + s);
      double v;
      if (yy < 0) {
        v = open ? 40.0 : closed(double(x), double(y));
      } else if (yy < band) {
        v = lip(double(x), double(y) - s);
      } else {
        v = chin(double(x), double(y));
      }
      f.pix[static_cast<size_t>(y * w + x)] =
          static_cast<std::uint8_t>(std::lround(std::clamp(v, 0.0, 255.0)));
    }
  }
  return f;
}

// Three points along the top of the lip band of `render_mouth` (y = y0), springs between
// neighbours, and tracker options with half patches below each point (the lip side).
struct LipRow {
  RowMatrixXd p0;
  SpringMesh mesh;
  TrackerOptions half;
};

LipRow lip_row(double y0) {
  LipRow row;
  row.p0.resize(3, 2);
  row.p0 << 60, y0, 100, y0, 140, y0;
  EdgeMatrix edges(2, 2);
  edges << 0, 1, 1, 2;
  row.mesh = springs_from_points(row.p0, edges);
  row.half.patch_sides = RowMatrixXd(3, 2);
  row.half.patch_sides << 0, 1, 0, 1, 0, 1;
  return row;
}

TEST_CASE("tracker: half patches follow a lip beside an opening mouth; search catches a jump") {
  const Texture lip(21), closed(22), chin(23);
  const double y0 = 70;
  const LipRow row = lip_row(y0);
  const RowMatrixXd& p0 = row.p0;
  const SpringMesh& mesh = row.mesh;
  const TrackerOptions& half = row.half;
  TrackerOptions searched = half;
  searched.search_radius = 12;
  const Frame f0 = render_mouth(lip, closed, chin, y0, 0, false);
  SpringMeshTracker whole_t(f0.view(), p0, mesh), half_t(f0.view(), p0, mesh, half),
      search_t(f0.view(), p0, mesh, searched);
  // The mouth opens 1.5 px per frame for 3 frames, then the lip drops 10 px in one frame.
  const std::vector<double> drop = {1.5, 3.0, 4.5, 14.5};
  double err_whole = 0, err_half = 0, err_search = 0;
  for (const double s : drop) {
    const Frame f = render_mouth(lip, closed, chin, y0, s, true);
    const TrackerFrame rw = whole_t.track(f.view()), rh = half_t.track(f.view()),
                       rs = search_t.track(f.view());
    err_whole = err_half = err_search = 0;
    for (Index i = 0; i < 3; ++i) {
      err_whole = std::max(err_whole, std::hypot(rw.points(i, 0) - p0(i, 0), rw.points(i, 1) - y0 - s));
      err_half = std::max(err_half, std::hypot(rh.points(i, 0) - p0(i, 0), rh.points(i, 1) - y0 - s));
      err_search = std::max(err_search, std::hypot(rs.points(i, 0) - p0(i, 0), rs.points(i, 1) - y0 - s));
    }
    MESSAGE("lip drop ", s, " px: worst error whole patches ", err_whole, ", half patches ",
            err_half, ", half patches + search ", err_search);
    if (s < 5) {
      // Gradual opening: the half patches keep the lip (they never see the cavity) ...
      CHECK(err_half < 0.1);
      CHECK(err_search < 0.1);
      CHECK(!rh.lost.any());
    }
  }
  // ... the whole patches, whose upper half turned from closed lips into a cavity, do not.
  CHECK(err_whole > 2.0);
  // A 7 px jump is beyond the gradient steps and the coarse levels (dominated by the static
  // chin); the exhaustive search finds it.
  CHECK(err_half > 2.0);
  CHECK(err_search < 0.1);
}

TEST_CASE("tracker: a group search finds a lower lip that dropped beyond the point search") {
  const Texture lip(21), closed(22), chin(23);
  const double y0 = 60;
  const LipRow row = lip_row(y0);
  const RowMatrixXd& p0 = row.p0;
  const SpringMesh& mesh = row.mesh;
  TrackerOptions alone = row.half;
  alone.search_radius = 6;
  TrackerOptions grouped = alone;
  grouped.search_groups.resize(3);
  grouped.search_groups << 0, 0, 0;
  grouped.group_search_radius = 18;
  const Frame f0 = render_mouth(lip, closed, chin, y0, 0, false);
  SpringMeshTracker a(f0.view(), p0, mesh, alone), g(f0.view(), p0, mesh, grouped);
  // A 15 px drop in one frame: beyond each point's 6 px search, within the group's 18 px.
  const Frame f = render_mouth(lip, closed, chin, y0, 15, true);
  const TrackerFrame ra = a.track(f.view()), rg = g.track(f.view());
  double err_alone = 0, err_group = 0;
  for (Index i = 0; i < 3; ++i) {
    err_alone = std::max(err_alone, std::hypot(ra.points(i, 0) - p0(i, 0), ra.points(i, 1) - y0 - 15));
    err_group = std::max(err_group, std::hypot(rg.points(i, 0) - p0(i, 0), rg.points(i, 1) - y0 - 15));
  }
  MESSAGE("15 px lip drop: worst error point search ", err_alone, " px, group search ", err_group, " px");
  CHECK(err_alone > 5.0);
  CHECK(err_group < 0.1);
  CHECK(!rg.lost.any());
  // Bad group ids are refused.
  TrackerOptions bad = grouped;
  bad.search_groups.resize(2);
  CHECK_THROWS_WITH_AS(SpringMeshTracker(f0.view(), p0, mesh, bad), doctest::Contains("search_groups"),
                       std::invalid_argument);
}

// The texture, except that the content under point 1 (a box around (73, 40)) has slid 6 px to
// the right: a feature its tracker may follow though the face has not moved.
Frame render_distractor(const Texture& tex, bool slid) {
  return render_with(130, 100, [&](double x, double y) {
    const bool box = slid && std::abs(x - 73) <= 12 && std::abs(y - 40) <= 9;
    return tex(x - (box ? 6.0 : 0.0), y);
  });
}

TEST_CASE("tracker: a point whose data contradict its springs by many sigmas is handed to them") {
  const Texture tex(5);
  RowMatrixXd p(4, 2);
  p << 40, 40, 70, 40, 55, 72, 85, 72;
  const EdgeMatrix e = delaunay_edges(p);
  SpringMesh mesh = springs_from_points(p, e);
  mesh.offset_precision = RowMatrixXd::Zero(e.rows(), 4);
  mesh.offset_mean = RowMatrixXd::Zero(e.rows(), 2);
  for (Index k = 0; k < e.rows(); ++k) {
    mesh.offset_precision.row(k) << 4, 0, 0, 4;  // 0.5 px in every direction
    mesh.offset_mean.row(k) = p.row(e(k, 1)) - p.row(e(k, 0));
    mesh.stiffness[k] = 0;
  }
  TrackerOptions plain;
  TrackerOptions checked = plain;
  checked.spring_outlier = 4;
  checked.outlier_edges.resize(e.rows());
  for (Index k = 0; k < e.rows(); ++k) checked.outlier_edges[k] = k;
  const Frame f0 = render_distractor(tex, false), f1 = render_distractor(tex, true);
  SpringMeshTracker a(f0.view(), p, mesh, plain), b(f0.view(), p, mesh, checked);
  const TrackerFrame ra = a.track(f1.view()), rb = b.track(f1.view());
  const double err_plain = (ra.points.row(1) - p.row(1)).norm(),
               err_checked = (rb.points.row(1) - p.row(1)).norm();
  MESSAGE("distracted point: error " << err_plain << " px without the check, " << err_checked
                                     << " px with it");
  CHECK(err_plain > 3.0);   // its data (a perfect match 6 px away) outweigh 0.5 px springs
  CHECK(err_checked < 0.3);  // muted: the springs hold it where its neighbours say
  for (const Index i : {Index(0), Index(2), Index(3)}) CHECK((rb.points.row(i) - p.row(i)).norm() < 0.3);
  TrackerOptions bad = checked;
  bad.outlier_edges[0] = e.rows();
  CHECK_THROWS_WITH_AS(SpringMeshTracker(f0.view(), p, mesh, bad), doctest::Contains("outlier_edges"),
                       std::invalid_argument);
}

TEST_CASE("tracker: a reference search finds a feature that jumped out of its patch") {
  // A bright blob on a flat disc (a feature, e.g. a mouth corner) in a static texture jumps
  // 12 px down in one frame: beyond its 13x13 patch, so the gradient steps on one level do not
  // reach it and its soft springs to the static points leave it behind. Searched for against
  // its first-frame template within 14 px, it is found, at the planted position.
  const Texture tex(31);
  const Index W = 200, H = 160;
  auto render_blob = [&](double bx, double by) {
    Frame f = render(tex, W, H, 0, 0);
    for (Index y = 0; y < H; ++y) {
      for (Index x = 0; x < W; ++x) {
        const double d2 = (x - bx) * (x - bx) + (y - by) * (y - by);
        if (d2 > 8.0 * 8.0) continue;
        const double v = 100.0 + 100.0 * std::exp(-d2 / (2 * 2.5 * 2.5));
        f.pix[static_cast<size_t>(y * W + x)] = static_cast<std::uint8_t>(std::lround(std::min(v, 255.0)));
      }
    }
    return f;
  };
  RowMatrixXd p0(4, 2);
  p0 << 100, 60, 60, 62, 140, 58, 101, 110;
  const SpringMesh mesh = springs_from_points(p0, delaunay_edges(p0), 0.5);  // std 20 px
  TrackerOptions plain;
  plain.levels = 1;
  TrackerOptions searched = plain;
  searched.reference_points = VectorXi::Constant(1, 0);
  searched.reference_search_radius = 14;
  SpringMeshTracker plain_t(render_blob(100, 60).view(), p0, mesh, plain),
      search_t(render_blob(100, 60).view(), p0, mesh, searched);
  // A frame where nothing moved: the search leaves every point where it is.
  const Frame still = render_blob(100, 60);
  const TrackerFrame s0 = search_t.track(still.view());
  plain_t.track(still.view());
  CHECK((s0.points - p0).cwiseAbs().maxCoeff() < 0.02);
  const Frame jumped = render_blob(100, 72);
  const TrackerFrame rp = plain_t.track(jumped.view()), rs = search_t.track(jumped.view());
  const double err_plain = std::hypot(rp.points(0, 0) - 100, rp.points(0, 1) - 72);
  const double err_search = std::hypot(rs.points(0, 0) - 100, rs.points(0, 1) - 72);
  MESSAGE("blob jumped 12 px: error without the reference search ", err_plain, " px, with it ", err_search,
          " px (confidence ", rs.confidence[0], ")");
  CHECK(err_plain > 5.0);
  CHECK(err_search < 0.1);
  CHECK(rs.confidence[0] > 0.9);
  // The static points stay put.
  CHECK((rs.points.bottomRows(3) - p0.bottomRows(3)).cwiseAbs().maxCoeff() < 0.05);
  // Bad options are refused with a reason.
  TrackerOptions bad = searched;
  bad.reference_points = VectorXi::Constant(1, 4);
  CHECK_THROWS_WITH_AS(SpringMeshTracker(still.view(), p0, mesh, bad), doctest::Contains("reference_points"),
                       std::invalid_argument);
  bad = searched;
  bad.reference_search_radius = -1;
  CHECK_THROWS_WITH_AS(SpringMeshTracker(still.view(), p0, mesh, bad),
                       doctest::Contains("reference_search_radius"), std::invalid_argument);
  bad = searched;
  bad.reference_search_ncc = 1.5;
  CHECK_THROWS_WITH_AS(SpringMeshTracker(still.view(), p0, mesh, bad),
                       doctest::Contains("reference_search_ncc"), std::invalid_argument);
}

TEST_CASE("tracker: a sided reference search finds a contour whose other side changed") {
  // An upper lip's edge: above y = e(t) horizontal stripes (texture in y only), below it a
  // texture that changes every frame (teeth, cavity). The edge drops 6 px in one frame. The
  // point's whole first-frame patch no longer matches anywhere (its lower half is gone), and
  // along the stripes every x matches; the half patch above the point, searched for along the
  // vertical only, finds the edge at the planted place.
  const Texture static_tex(41), stripes(42);
  const Index W = 200, H = 160;
  auto render_edge = [&](double e, unsigned below_seed) {
    const Texture below(below_seed);
    Frame f = render(static_tex, W, H, 0, 0);
    for (Index y = 50; y < 100; ++y) {
      for (Index x = 70; x < 130; ++x) {
        const double u = double(y) - e;
        const double v = u < 0 ? stripes(17.0, 3.0 * u) : below(double(x), double(y));
        f.pix[static_cast<size_t>(y * W + x)] = static_cast<std::uint8_t>(std::lround(std::clamp(v, 0.0, 255.0)));
      }
    }
    return f;
  };
  RowMatrixXd p0(4, 2);
  p0 << 100, 70, 30, 40, 170, 42, 101, 140;
  const SpringMesh mesh = springs_from_points(p0, delaunay_edges(p0), 0.5);  // std of 10-50 px
  TrackerOptions whole;
  whole.levels = 1;
  whole.reference_points = VectorXi::Constant(1, 0);
  whole.reference_search_radius = 9;
  TrackerOptions sided = whole;
  sided.reference_sides = RowMatrixXd::Zero(4, 2);
  sided.reference_sides(0, 1) = -1;  // the half patch above the point, searched for vertically
  const Frame f0 = render_edge(70, 1);
  SpringMeshTracker whole_t(f0.view(), p0, mesh, whole), sided_t(f0.view(), p0, mesh, sided);
  const Frame f1 = render_edge(76, 2);
  const TrackerFrame rw = whole_t.track(f1.view()), rs = sided_t.track(f1.view());
  // Across the contour (y) the data decide; along it (x) the stripes say nothing.
  const double err_whole = std::abs(rw.points(0, 1) - 76), err_sided = std::abs(rs.points(0, 1) - 76);
  MESSAGE("edge dropped 6 px: error across it with the whole-patch reference search ", err_whole,
          " px, with the sided one ", err_sided, " px (along it: ", rw.points(0, 0) - 100, ", ",
          rs.points(0, 0) - 100, " px)");
  CHECK(err_whole > 2.0);
  // Whole-pixel steps from where stage A left it (0.38 px: its stage B answer, against the whole
  // first-frame patch, is rejected, so the search's grid stays).
  CHECK(err_sided < 0.5);
  CHECK(std::abs(rs.points(0, 0) - rw.points(0, 0)) < 1e-9);  // the search moved it across only
  CHECK((rs.points.bottomRows(3) - p0.bottomRows(3)).cwiseAbs().maxCoeff() < 0.05);
  TrackerOptions bad = sided;
  bad.reference_sides = RowMatrixXd::Zero(3, 2);
  CHECK_THROWS_WITH_AS(SpringMeshTracker(f0.view(), p0, mesh, bad), doctest::Contains("reference_sides"),
                       std::invalid_argument);
}

TEST_CASE("tracker: a sub-pixel shift of a textured image is recovered to 0.06 px") {
  const Texture tex(3);
  const Frame f0 = render(tex, 200, 160, 0, 0);
  const RowMatrixXd p0 = grid_points(4, 3, 50, 40, 30);
  const SpringMesh mesh = springs_from_points(p0, delaunay_edges(p0));
  for (const auto& [dx, dy] : std::vector<std::pair<double, double>>{{0.37, -0.81}, {-0.6, 0.25}}) {
    SpringMeshTracker tracker(f0.view(), p0, mesh);
    const TrackerFrame r = tracker.track(render(tex, 200, 160, dx, dy).view());
    for (Index i = 0; i < p0.rows(); ++i) {
      CHECK(std::abs(r.points(i, 1) - p0(i, 1) - dy) < 0.06);
      CHECK(std::abs(r.points(i, 0) - p0(i, 0) - dx) < 0.06);
      CHECK(!r.lost[i]);
      CHECK(r.confidence[i] > 0.95);
    }
  }
}

// Renders the texture seen through the similarity A about c, then moved by b: the content
// at x in frame 0 is at c + A (x - c) + b (rotation and scale of the whole picture).
Frame render_similar(const Texture& tex, Index w, Index h, const Eigen::Matrix2d& A,
                     const Eigen::Vector2d& c, const Eigen::Vector2d& b) {
  Frame f{std::vector<std::uint8_t>(static_cast<size_t>(w * h)), w, h};
  const Eigen::Matrix2d Ai = A.inverse();
  for (Index y = 0; y < h; ++y) {
    for (Index x = 0; x < w; ++x) {
      const Eigen::Vector2d src = c + Ai * (Eigen::Vector2d(double(x), double(y)) - c - b);
      f.pix[static_cast<size_t>(y * w + x)] =
          static_cast<std::uint8_t>(std::lround(std::clamp(tex(src[0], src[1]), 0.0, 255.0)));
    }
  }
  return f;
}

Eigen::Matrix2d similarity(double angle, double scale) {
  return (Eigen::Matrix2d() << std::cos(angle), -std::sin(angle), std::sin(angle), std::cos(angle))
             .finished() * scale;
}

TEST_CASE("tracker: first-frame templates and springs follow a face that turns 30 degrees and scales") {
  // A textured picture turns from 0 to 30 degrees while it grows to 1.4 times its size, then
  // turns back while it shrinks to 0.75 (0.75 degrees and about 1 % per frame), drifting
  // sideways. With frame points the first-frame templates are re-cut through the pose, the
  // springs' rest lengths scale with it, and every point stays within a fraction of a pixel
  // of the planted position, matching its first-frame template. Without frame points (the
  // image frame) the first-frame templates decorrelate: points are flagged lost, and their
  // stiff springs, still at the first frame's lengths, pull them off.
  const Texture tex(21);
  const Index W = 320, H = 280;
  const Eigen::Vector2d c(160, 140);
  const RowMatrixXd p0 = grid_points(4, 4, 115, 95, 30);
  const SpringMesh mesh = springs_from_points(p0, delaunay_edges(p0));
  const Frame f0 = render_similar(tex, W, H, Eigen::Matrix2d::Identity(), c, Eigen::Vector2d::Zero());
  TrackerOptions image_frame;
  TrackerOptions face_frame;
  face_frame.frame_points = VectorXi::LinSpaced(p0.rows(), 0, static_cast<int>(p0.rows()) - 1);
  SpringMeshTracker plain(f0.view(), p0, mesh, image_frame), posed(f0.view(), p0, mesh, face_frame);
  const double deg = 3.14159265358979 / 180;
  double worst_posed = 0, worst_plain = 0, min_conf = 1, sum_posed = 0, sum_plain = 0;
  Index lost_posed = 0, lost_plain = 0;
  const int n = 80;
  for (int t = 1; t <= n; ++t) {
    const double u = double(t) / n;  // 0 .. 1
    const double angle = 30 * deg * std::sin(3.14159265358979 * u);
    const double scale = u < 0.5 ? 1 + 0.8 * u : 1.4 - 1.3 * (u - 0.5);
    const Eigen::Matrix2d A = similarity(angle, scale);
    const Eigen::Vector2d b(8 * std::sin(6.283185307179586 * u), -5 * u);
    const Frame f = render_similar(tex, W, H, A, c, b);
    const TrackerFrame rp = posed.track(f.view()), rq = plain.track(f.view());
    for (Index i = 0; i < p0.rows(); ++i) {
      const Eigen::Vector2d truth = c + A * (p0.row(i).transpose() - c) + b;
      const double ep = (rp.points.row(i).transpose() - truth).norm();
      const double eq = (rq.points.row(i).transpose() - truth).norm();
      worst_posed = std::max(worst_posed, ep);
      worst_plain = std::max(worst_plain, eq);
      sum_posed += ep;
      sum_plain += eq;
      min_conf = std::min(min_conf, rp.confidence[i]);
    }
    lost_posed += rp.lost.count();
    lost_plain += rq.lost.count();
  }
  const double mean_posed = sum_posed / double(n * p0.rows()), mean_plain = sum_plain / double(n * p0.rows());
  MESSAGE("turn to 30 deg, scale 1.4 -> 0.75: error with frame points mean ", mean_posed, " px, worst ",
          worst_posed, " px (lowest confidence ", min_conf, ", ", lost_posed,
          " point-frames lost); without: mean ", mean_plain, " px, worst ", worst_plain, " px (", lost_plain,
          " lost)");
  CHECK(mean_posed < 0.1);
  CHECK(worst_posed < 0.4);
  CHECK(lost_posed == 0);
  CHECK(min_conf > 0.95);
  CHECK(mean_plain > 1.0);
  CHECK(worst_plain > 5.0);
  CHECK(lost_plain > 0);
}

TEST_CASE("estimate_springs: with frame points, lengths are measured in the face frame") {
  // A triangle scaled by 1, 2, 3 and turned: in the face frame (the similarity of all its
  // points to frame 0's) its sides do not change, so the rest lengths are frame 0's and the
  // stiffnesses sit at the variance floor; in the image frame they are the means of the
  // scaled lengths.
  const RowMatrixXd p = triangle_3_4_5();
  const EdgeMatrix e = triangle_edges();
  const SpringMesh m = springs_from_points(p, e, 0.1);
  RowMatrixXd tracks(3, 6);
  for (int t = 0; t < 3; ++t) {
    const Eigen::Matrix2d A = similarity(0.2 * t, t + 1.0);
    for (Index i = 0; i < 3; ++i) {
      const Eigen::Vector2d q = A * p.row(i).transpose() + Eigen::Vector2d(5.0 * t, -2.0 * t);
      tracks(t, 2 * i) = q[0];
      tracks(t, 2 * i + 1) = q[1];
    }
  }
  const RowMatrixXb none = RowMatrixXb::Zero(3, 3);
  const SpringMesh face = estimate_springs(tracks, none, m, 0.5, VectorXi::LinSpaced(3, 0, 2));
  const SpringMesh image = estimate_springs(tracks, none, m, 0.5);
  for (Index k = 0; k < 3; ++k) {
    CHECK(face.rest_length[k] == doctest::Approx(m.rest_length[k]).epsilon(1e-9));
    CHECK(face.stiffness[k] == doctest::Approx(4.0));
    CHECK(image.rest_length[k] == doctest::Approx(2 * m.rest_length[k]).epsilon(1e-9));
  }
  // A lost frame point gives no face frame: frame 2 with point 1 lost and moved far away keeps
  // the face frame of the other two points (which, with 2 points, is still exact).
  RowMatrixXd moved = tracks;
  moved(2, 2) += 40;
  RowMatrixXb lost = none;
  lost(2, 1) = true;
  const SpringMesh held = estimate_springs(moved, lost, m, 0.5, VectorXi::LinSpaced(3, 0, 2));
  CHECK(held.rest_length[1] == doctest::Approx(m.rest_length[1]).epsilon(1e-9));  // edge 0-2
  // A frame point that slid off its feature without being flagged lost is left out of the face
  // frame by the robust refit: a 3 x 3 grid turned and scaled, its corner point 0 moved 10 px in
  // one frame; the springs between the other points keep their frame-0 lengths exactly.
  const RowMatrixXd g = grid_points(3, 3, 0, 0, 20);
  const EdgeMatrix ge = delaunay_edges(g);
  const SpringMesh gm = springs_from_points(g, ge, 0.1);
  RowMatrixXd gt(3, 18);
  for (int t = 0; t < 3; ++t) {
    const Eigen::Matrix2d A = similarity(0.15 * t, 1 + 0.2 * t);
    for (Index i = 0; i < 9; ++i) {
      const Eigen::Vector2d q = A * g.row(i).transpose();
      gt(t, 2 * i) = q[0];
      gt(t, 2 * i + 1) = q[1];
    }
  }
  gt(2, 0) += 10;
  // (a wide outlier band, 3 x 5 px: the refit, not the band, must keep frame 2 right)
  const SpringMesh gr = estimate_springs(gt, RowMatrixXb::Zero(3, 9), gm, 5.0, VectorXi::LinSpaced(9, 0, 8));
  Index checked_edges = 0;
  for (Index k = 0; k < ge.rows(); ++k) {
    if (ge(k, 0) == 0) continue;
    CHECK(gr.rest_length[k] == doctest::Approx(gm.rest_length[k]).epsilon(1e-9));
    ++checked_edges;
  }
  CHECK(checked_edges >= 8);
}

TEST_CASE("tracker: a 9 px jump with a brightness change is caught by the pyramid") {
  const Texture tex(11);
  const Frame f0 = render(tex, 240, 200, 0, 0);
  const RowMatrixXd p0 = grid_points(4, 4, 60, 50, 30);
  SpringMeshTracker tracker(f0.view(), p0, springs_from_points(p0, delaunay_edges(p0)));
  CHECK(tracker.levels() == 3);
  const TrackerFrame r = tracker.track(render(tex, 240, 200, 9.2, -6.7, 0.7, 30).view());
  for (Index i = 0; i < p0.rows(); ++i) {
    CHECK(std::abs(r.points(i, 0) - p0(i, 0) - 9.2) < 0.05);
    CHECK(std::abs(r.points(i, 1) - p0(i, 1) + 6.7) < 0.05);
  }
}

TEST_CASE("tracker: an occluded point is carried by its springs and flagged lost") {
  const Texture tex(5);
  const Frame f0 = render(tex, 220, 180, 0, 0);
  const RowMatrixXd p0 = grid_points(4, 3, 50, 45, 35);
  SpringMeshTracker tracker(f0.view(), p0, springs_from_points(p0, delaunay_edges(p0)));
  const Index hidden = 5;
  TrackerFrame r;
  double dx = 0, dy = 0;
  for (int t = 1; t <= 6; ++t) {
    dx = 1.3 * t;
    dy = -0.7 * t;
    Frame f = render(tex, 220, 180, dx, dy);
    // A flat grey card over the hidden point from frame 2 to 4.
    if (t >= 2 && t <= 4) {
      const Index cx = std::lround(p0(hidden, 0) + dx), cy = std::lround(p0(hidden, 1) + dy);
      for (Index y = cy - 10; y <= cy + 10; ++y) {
        for (Index x = cx - 10; x <= cx + 10; ++x) f.pix[static_cast<size_t>(y * f.w + x)] = 90;
      }
    }
    r = tracker.track(f.view());
    const double ex = r.points(hidden, 0) - p0(hidden, 0) - dx;
    const double ey = r.points(hidden, 1) - p0(hidden, 1) - dy;
    CHECK(std::hypot(ex, ey) < (t >= 2 && t <= 4 ? 1.0 : 0.05));
    CHECK(r.lost[hidden] == (t >= 2 && t <= 4));
  }
}

TEST_CASE("tracker: points leaving the frame are flagged lost, never a crash") {
  const Texture tex(9);
  const Frame f0 = render(tex, 160, 120, 0, 0);
  const RowMatrixXd p0 = grid_points(3, 3, 30, 30, 25);
  SpringMeshTracker tracker(f0.view(), p0, springs_from_points(p0, delaunay_edges(p0)));
  TrackerFrame r;
  for (int t = 1; t <= 40; ++t) r = tracker.track(render(tex, 160, 120, -3.0 * t, 0).view());
  CHECK(r.points.allFinite());
  CHECK(r.lost.count() == p0.rows());
}

TEST_CASE("tracker: bad input is refused with a reason") {
  const Texture tex(1);
  const Frame f0 = render(tex, 100, 80, 0, 0);
  RowMatrixXd p(3, 2);
  p << 20, 20, 60, 25, 40, 60;
  const SpringMesh mesh = springs_from_points(p, delaunay_edges(p));
  RowMatrixXd outside = p;
  outside(1, 0) = 130;
  CHECK_THROWS_WITH_AS(SpringMeshTracker(f0.view(), outside, mesh),
                       doctest::Contains("outside"), std::invalid_argument);
  CHECK_THROWS_WITH_AS(SpringMeshTracker(f0.view(), p.topRows(2), mesh),
                       doctest::Contains("at least 3"), std::invalid_argument);
  CHECK_THROWS_AS(SpringMeshTracker(GreyImage{}, p, mesh), std::invalid_argument);
  TrackerOptions bad;
  bad.ncc_floor = 0.9;
  CHECK_THROWS_WITH_AS(SpringMeshTracker(f0.view(), p, mesh, bad), doctest::Contains("ncc_floor"),
                       std::invalid_argument);
  TrackerOptions sides;
  sides.patch_sides = RowMatrixXd::Zero(2, 2);
  CHECK_THROWS_WITH_AS(SpringMeshTracker(f0.view(), p, mesh, sides),
                       doctest::Contains("patch_sides"), std::invalid_argument);
  TrackerOptions search;
  search.search_radius = -1;
  CHECK_THROWS_WITH_AS(SpringMeshTracker(f0.view(), p, mesh, search),
                       doctest::Contains("search_radius"), std::invalid_argument);
  SpringMeshTracker tracker(f0.view(), p, mesh);
  const Frame small = render(tex, 90, 80, 0, 0);
  CHECK_THROWS_WITH_AS(tracker.track(small.view()), doctest::Contains("one size"),
                       std::invalid_argument);
  SpringMesh broken = mesh;
  broken.edges(0, 1) = 7;
  CHECK_THROWS_WITH_AS(SpringMeshTracker(f0.view(), p, broken), doctest::Contains("outside"),
                       std::invalid_argument);
}

TEST_CASE("tracker: relocate restarts lost points where the texture came back, as a fresh tracker") {
  // The textured face leaves (a flat frame: every point lost), then comes back 60 px away,
  // beyond the pyramid's reach. Relocated there, the tracker answers exactly as a tracker
  // constructed on the first frame at the first-frame points answers the same shifted frame
  // from the same start, with the image frame and with a face frame (frame_points).
  const Texture tex(21);
  const Index w = 260, h = 200;
  const Frame f0 = render(tex, w, h, 0, 0);
  const RowMatrixXd p0 = grid_points(3, 3, 50, 40, 30);
  const SpringMesh mesh = springs_from_points(p0, delaunay_edges(p0));
  Frame flat = f0;
  std::fill(flat.pix.begin(), flat.pix.end(), std::uint8_t{100});
  const double dx = 61.4, dy = 23.2;
  const Frame back = render(tex, w, h, dx, dy);
  RowMatrixXd moved = p0;
  moved.col(0).array() += 57.0;  // a few pixels off (a coarse search's answer): the pyramid
  moved.col(1).array() += 20.0;  // takes it from there
  for (const bool with_frame : {false, true}) {
    CAPTURE(with_frame);
    TrackerOptions opt;
    if (with_frame) opt.frame_points = (VectorXi(4) << 0, 2, 6, 8).finished();
    SpringMeshTracker tracker(f0.view(), p0, mesh, opt);
    TrackerFrame r;
    // The face moves a little first (the current templates are re-cut where it went) ...
    for (int t = 1; t <= 3; ++t) r = tracker.track(render(tex, w, h, 1.3 * t, -0.7 * t).view());
    CHECK(r.lost.count() == 0);
    // ... then leaves.
    for (int t = 0; t < 3; ++t) r = tracker.track(flat.view());
    CHECK(r.lost.count() == p0.rows());
    // Without a restart the texture is not found again.
    SpringMeshTracker stays = std::move(tracker);
    SpringMeshTracker control(f0.view(), p0, mesh, opt);
    for (int t = 0; t < 3; ++t) control.track(flat.view());
    const TrackerFrame missed = control.track(back.view());
    double missed_by = 0;
    for (Index i = 0; i < p0.rows(); ++i) {
      missed_by += std::hypot(missed.points(i, 0) - p0(i, 0) - dx, missed.points(i, 1) - p0(i, 1) - dy);
    }
    CHECK(missed_by / double(p0.rows()) > 40.0);
    stays.relocate(moved);
    CHECK(stays.points() == moved);
    const TrackerFrame found = stays.track(back.view());
    CHECK(found.lost.count() == 0);
    for (Index i = 0; i < p0.rows(); ++i) {
      CHECK(std::abs(found.points(i, 0) - p0(i, 0) - dx) < 0.05);
      CHECK(std::abs(found.points(i, 1) - p0(i, 1) - dy) < 0.05);
    }
    // A fresh tracker on the first frame, restarted at the same points, answers bit for bit alike.
    SpringMeshTracker fresh(f0.view(), p0, mesh, opt);
    fresh.relocate(moved);
    const TrackerFrame same = fresh.track(back.view());
    CHECK(same.points == found.points);
    CHECK(same.confidence == found.confidence);
    CHECK(same.lost == found.lost);
    // Bad input.
    CHECK_THROWS_WITH_AS(stays.relocate(p0.topRows(2)), doctest::Contains("shape (9, 2)"),
                         std::invalid_argument);
    RowMatrixXd nan = p0;
    nan(4, 1) = std::nan("");
    CHECK_THROWS_WITH_AS(stays.relocate(nan), doctest::Contains("points"), std::invalid_argument);
  }
}

// Three points on each half of a `render_halves` frame.
RowMatrixXd halves_points() {
  RowMatrixXd p(6, 2);
  p << 40, 50, 40, 95, 65, 72, 160, 54, 160, 105, 135, 82;
  return p;
}

// Texture A on the left half of a 200 x 140 frame, texture B on the right half raised by `rise` px.
Frame render_halves(const Texture& ta, const Texture& tb, double rise) {
  return render_with(200, 140, [&](double x, double y) { return x < 100 ? ta(x, y) : tb(x, y + rise); });
}

TEST_CASE("tracker: ordered points never cross, whatever their data say") {
  const Texture ta(21), tb(22);
  // Three points on each half; point 0 (left, y 50) is to stay above point 3 (right, y 60).
  const RowMatrixXd p = halves_points();
  const SpringMesh mesh = springs_from_points(p, delaunay_edges(p), 0.5);  // weak springs
  EdgeMatrix order(1, 2);
  order << 0, 3;
  // The right half rises 8 px: point 3 ends 4 px above point 0.
  const Frame f0 = render_halves(ta, tb, 0), f1 = render_halves(ta, tb, 8);
  SpringMeshTracker loose(f0.view(), p, mesh);  // control: free, the pair crosses
  const TrackerFrame a = loose.track(f1.view());
  CHECK(std::abs(a.points(3, 1) - 46) < 0.5);
  CHECK(std::abs(a.points(0, 1) - 50) < 0.5);
  TrackerOptions ordered;
  ordered.order_pairs = order;
  SpringMeshTracker tracker(f0.view(), p, mesh, ordered);
  const TrackerFrame b = tracker.track(f1.view());
  CHECK(b.points(3, 1) >= b.points(0, 1) - 1e-9);  // on the order
  CHECK(b.points(3, 1) - b.points(0, 1) < 1.0);    // held at it, not pushed apart
  CHECK(std::abs(b.points(0, 0) - 40) < 2);
  CHECK(std::abs(b.points(3, 0) - 160) < 2);
  // Along another axis only that axis's component is ordered: along x the pair (point 3 to the
  // right of point 0) is in order and tracks as the free one does.
  TrackerOptions sideways = ordered;
  sideways.order_axis = Eigen::Vector2d(1.0, 0.0);
  SpringMeshTracker side(f0.view(), p, mesh, sideways);
  const TrackerFrame c = side.track(f1.view());
  CHECK(std::abs(c.points(3, 1) - 46) < 0.5);
  // Bad orders are refused with a reason.
  TrackerOptions bad = ordered;
  bad.order_pairs(0, 1) = 9;
  CHECK_THROWS_WITH_AS(SpringMeshTracker(f0.view(), p, mesh, bad), doctest::Contains("order_pairs"),
                       std::invalid_argument);
  bad = ordered;
  bad.order_axis = Eigen::Vector2d(0.0, 0.0);
  CHECK_THROWS_WITH_AS(SpringMeshTracker(f0.view(), p, mesh, bad), doctest::Contains("order_axis"),
                       std::invalid_argument);
  bad = ordered;
  bad.order_margin = -1.0;
  CHECK_THROWS_WITH_AS(SpringMeshTracker(f0.view(), p, mesh, bad), doctest::Contains("order_margin"),
                       std::invalid_argument);
  // A margin lets the pair overlap by that much and no more.
  TrackerOptions loose_order = ordered;
  loose_order.order_margin = 2.0;
  SpringMeshTracker margin(f0.view(), p, mesh, loose_order);
  const TrackerFrame m = margin.track(f1.view());
  CHECK(m.points(3, 1) >= m.points(0, 1) - 2.0 - 1e-9);
  CHECK(m.points(3, 1) - m.points(0, 1) < -1.0);
}

TEST_CASE("tracker: anchors pull a point only beyond their slack") {
  const Texture ta(21), tb(22);
  const RowMatrixXd p = halves_points();
  const SpringMesh mesh = springs_from_points(p, delaunay_edges(p), 0.5);
  // The right half rises 8 px: its data put point 3 at y 46.
  const Frame f0 = render_halves(ta, tb, 0), f1 = render_halves(ta, tb, 8);
  SpringMeshTracker free_tracker(f0.view(), p, mesh);
  const TrackerFrame free_answer = free_tracker.track(f1.view());
  REQUIRE(std::abs(free_answer.points(3, 1) - 46) < 0.5);
  TrackerOptions anchored;
  anchored.anchor_precision = VectorXd::Zero(6);
  anchored.anchor_precision[3] = 1e4;
  RowMatrixXd none = RowMatrixXd::Constant(6, 2, std::nan(""));
  // No anchor (NaN rows) and an anchor within its slack leave the answer bit for bit.
  SpringMeshTracker a(f0.view(), p, mesh, anchored);
  CHECK(a.track(f1.view(), none).points == free_answer.points);
  RowMatrixXd near = none;
  near.row(3) << 160, 50;  // 4 px from where the data put the point
  anchored.anchor_slack = VectorXd::Constant(6, 5.0);
  SpringMeshTracker b(f0.view(), p, mesh, anchored);
  CHECK(b.track(f1.view(), near).points == free_answer.points);
  // Beyond the slack a stiff anchor holds the point at the slack's edge: |y - 56| = 1.
  RowMatrixXd far = none;
  far.row(3) << 160, 56;
  anchored.anchor_slack = VectorXd::Constant(6, 1.0);
  SpringMeshTracker c(f0.view(), p, mesh, anchored);
  const TrackerFrame held = c.track(f1.view(), far);
  CHECK(held.points(3, 1) == doctest::Approx(55).epsilon(0.01));
  // The slack is per point: point 3 without any is held on its anchor, the others' slack aside.
  anchored.anchor_slack = VectorXd::Constant(6, 5.0);
  anchored.anchor_slack[3] = 0.0;
  SpringMeshTracker tight(f0.view(), p, mesh, anchored);
  CHECK(tight.track(f1.view(), far).points(3, 1) == doctest::Approx(56).epsilon(0.01));
  CHECK(std::abs(held.points(0, 1) - 50) < 0.5);  // the others still follow their data
  // Bad anchors and anchor options are refused with a reason.
  CHECK_THROWS_WITH_AS(c.track(f1.view(), RowMatrixXd::Zero(5, 2)), doctest::Contains("anchors"),
                       std::invalid_argument);
  RowMatrixXd inf = none;
  inf(2, 0) = std::numeric_limits<double>::infinity();
  CHECK_THROWS_WITH_AS(c.track(f1.view(), inf), doctest::Contains("infinite"), std::invalid_argument);
  TrackerOptions bad = anchored;
  bad.anchor_precision = VectorXd::Ones(4);
  CHECK_THROWS_WITH_AS(SpringMeshTracker(f0.view(), p, mesh, bad), doctest::Contains("anchor_precision"),
                       std::invalid_argument);
  for (const VectorXd& slack : {VectorXd(VectorXd::Constant(6, -1.0)), VectorXd(VectorXd::Ones(5))}) {
    bad = anchored;
    bad.anchor_slack = slack;
    CHECK_THROWS_WITH_AS(SpringMeshTracker(f0.view(), p, mesh, bad), doctest::Contains("anchor_slack"),
                         std::invalid_argument);
  }
}
