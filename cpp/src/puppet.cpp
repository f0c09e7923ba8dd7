#include "voicepuppet/puppet.hpp"

#include "voicepuppet/hmm.hpp"
#include "voicepuppet/limits.hpp"

#include <Eigen/Cholesky>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <string>
#include <utility>

namespace voicepuppet {
namespace {

/// The array `name`, checked to have `ndim` dimensions whose sizes match `dims` (−1: any).
const PuppetArray& array(const PuppetFile& f, const std::string& name, std::vector<long long> dims,
                         PuppetArray::DType dtype = PuppetArray::DType::Float64) {
  const PuppetArray& a = f.at(name);
  bool ok = a.shape.size() == dims.size() && a.dtype == dtype;
  for (size_t k = 0; ok && k < dims.size(); ++k) {
    ok = dims[k] < 0 || static_cast<long long>(a.shape[k]) == dims[k];
  }
  if (!ok) {
    std::string want, got;
    for (auto d : dims) want += (want.empty() ? "" : ", ") + (d < 0 ? std::string("*") : std::to_string(d));
    for (auto d : a.shape) got += (got.empty() ? "" : ", ") + std::to_string(d);
    fail_argument("puppet array '", name, "' must be ",
                  dtype == PuppetArray::DType::Int64 ? "int64" : "float64", " of shape (", want,
                  "), got ", a.dtype == PuppetArray::DType::Int64 ? "int64" : "float64", " (", got,
                  "); the file is damaged or from an incompatible tool");
  }
  if (dtype == PuppetArray::DType::Float64) {
    for (double v : a.f64) {
      if (!std::isfinite(v)) fail_argument("puppet array '", name, "' contains NaN or infinite values");
    }
  }
  return a;
}

/// Runs `check` on the array `name`, naming the array in the std::invalid_argument it throws.
template <class F>
void check_array(const std::string& name, F&& check) {
  try {
    check();
  } catch (const std::invalid_argument& e) {
    fail_argument("puppet array '", name, "' is not valid: ", e.what());
  }
}

constexpr const char* kDamaged = "the file is damaged or from an incompatible tool";

/// "<n> frames at <fps> fps", for the messages of the frame limits.
std::string frames_at(Index n, double fps) {
  std::ostringstream os;
  os << n << " frames at " << fps << " fps";
  return os.str();
}

/// The context map stored as the arrays `map`, `offset`, `context` (int) and `columns` (int):
/// columns in [1, n_columns], context in [0, 100], map rows columns·(2·context+1), `outputs`
/// columns (−1: any, at least one).
ContextMap read_context_map(const PuppetFile& f, const std::string& map, const std::string& offset,
                            const std::string& context, const std::string& columns, Index n_columns,
                            Index outputs) {
  ContextMap m;
  m.context = array(f, context, {1}, PuppetArray::DType::Int64).i64[0];
  m.columns = array(f, columns, {1}, PuppetArray::DType::Int64).i64[0];
  if (m.context < 0 || m.context > 100) fail_argument("puppet ", context, " must be in [0, 100], got ", m.context);
  if (m.columns < 1 || m.columns > n_columns) {
    fail_argument("puppet ", columns, " must be in [1, ", n_columns, "], got ", m.columns);
  }
  m.map = array(f, map, {m.columns * (2 * m.context + 1), outputs}).matrix();
  if (m.map.cols() < 1) fail_argument("puppet ", map, " must have at least one column");
  m.offset = array(f, offset, {m.map.cols()}).matrix().row(0).transpose();
  return m;
}

/// Whether a coordinate of pixel landmarks #T by 2P is not finite or beyond ±kMaxPixel; if so,
/// (t, j) is the first that is not finite, or else the farthest.
bool beyond_pixels(const RowMatrixXd& points, Index& t, Index& j) {
  if (points.size() == 0) return false;
  if (points.allFinite()) return points.cwiseAbs().maxCoeff(&t, &j) > kMaxPixel;
  const double* d = points.data();  // NaN is not ordered: maxCoeff may pass over it
  const Index k = std::find_if(d, d + points.size(), [](double v) { return !std::isfinite(v); }) - d;
  t = k / points.cols();
  j = k % points.cols();
  return true;
}

/// The parts' face coordinates side by side.
RowMatrixXd side_by_side(const std::vector<RowMatrixXd>& faces, Index n_dims) {
  RowMatrixXd out(faces.front().rows(), n_dims);
  Index col = 0;
  for (const auto& y : faces) {
    out.middleCols(col, y.cols()) = y;
    col += y.cols();
  }
  return out;
}

}  // namespace

RowMatrixXd ContextMap::apply(const MatrixRef& z) const {
  if (z.cols() < columns) fail_argument("a context map reads ", columns, " columns, got ", z.cols());
  const Index T = z.rows(), C = columns, k = context;
  // The stacked context rows are built and multiplied a block of frames at a time: the whole
  // stack would be T·C·(2k+1) doubles (230 MB for an hour at 30 fps, C = 24, k = 5).
  constexpr Index kRows = 512;
  RowMatrixXd out(T, map.cols());
  RowMatrixXd x(std::min(T, kRows), C * (2 * k + 1));
  for (Index t0 = 0; t0 < T; t0 += kRows) {
    const Index n = std::min(kRows, T - t0);
    for (Index i = 0; i < n; ++i) {
      for (Index j = -k; j <= k; ++j) {
        const Index s = std::clamp<Index>(t0 + i + j, 0, T - 1);
        x.row(i).segment((j + k) * C, C) = z.row(s).head(C);
      }
    }
    out.middleRows(t0, n).noalias() = x.topRows(n) * map;
  }
  out.rowwise() += offset.transpose();
  return out;
}

RowMatrixXd append_deltas(const MatrixRef& x, Index width) {
  if (width < 0) fail_argument("delta width must be >= 0, got ", width);
  if (width == 0) return x;
  const Index T = x.rows(), A = x.cols();
  RowMatrixXd out(T, 2 * A);
  out.leftCols(A) = x;
  out.rightCols(A).setZero();
  double norm = 0;
  for (Index k = 1; k <= width; ++k) norm += 2.0 * static_cast<double>(k * k);
  for (Index t = 0; t < T; ++t) {
    for (Index k = 1; k <= width; ++k) {
      const Index ahead = std::min(t + k, T - 1), behind = std::max(t - k, Index(0));
      out.row(t).rightCols(A) += (static_cast<double>(k) / norm) * (x.row(ahead) - x.row(behind));
    }
  }
  return out;
}

Puppet::Puppet(PuppetFile file) : file_(std::move(file)) {
  const auto& f = file_;
  check_utf8(f.metadata, "the puppet's metadata");
  check_json_depth(f.metadata, "the puppet's metadata");
  fps_ = array(f, "fps", {1}).f64[0];
  check_range("puppet fps", fps_, kMinFps, kMaxFps, kDamaged);
  if (f.arrays.count("audio/delta_width")) {
    delta_width_ = array(f, "audio/delta_width", {1}, PuppetArray::DType::Int64).i64[0];
    check_range<Index>("puppet audio/delta_width", delta_width_, 0, 100, kDamaged);
  }
  audio_mean_ = array(f, "audio/mean", {-1}).matrix().row(0).transpose();
  const Index A = audio_mean_.size();
  if (delta_width_ > 0 && A % 2) fail_argument("puppet audio/mean must hold features and their deltas (an even count), got ", A);
  check_range<Index>("puppet audio columns (audio/mean without deltas)", n_features(), 1, kMaxDims, kDamaged);
  audio_std_ = array(f, "audio/std", {A}).matrix().row(0).transpose();
  if ((audio_std_.array() <= 0).any()) fail_argument("puppet audio/std must be positive; ", kDamaged);
  if (f.arrays.count("audio/projection")) {
    projection_ = read_context_map(f, "audio/projection", "audio/projection_offset", "audio/projection_context",
                                   "audio/projection_columns", A, -1);
  }
  const Index V = n_vocal();
  check_range<Index>("puppet vocal features (columns of audio/projection)", V, 1, kMaxDims, kDamaged);
  mean_shape_ = array(f, "face/mean_shape", {-1, 2}).matrix();
  const Index P = mean_shape_.rows();
  check_range<Index>("puppet points (rows of face/mean_shape)", P, 1, kMaxPoints, kDamaged);
  mean_pose_ = array(f, "face/mean_pose", {4}).matrix().row(0).transpose();
  check_range("puppet face/mean_pose[0] (log scale)", mean_pose_(0), -kMaxLogScale, kMaxLogScale, kDamaged);
  check_range("puppet face/mean_pose[2] (x translation, px)", mean_pose_(2), -kMaxPixel, kMaxPixel, kDamaged);
  check_range("puppet face/mean_pose[3] (y translation, px)", mean_pose_(3), -kMaxPixel, kMaxPixel, kDamaged);

  std::vector<int> seen(static_cast<size_t>(P), 0);
  for (Index p = 0; f.arrays.count("face/part" + std::to_string(p) + "/points"); ++p) {
    check_range<Index>("puppet face parts", p + 1, 1, kMaxParts, kDamaged);
    const std::string fp = "face/part" + std::to_string(p) + "/", hp = "hmm/part" + std::to_string(p) + "/";
    PuppetPart part;
    const auto& pts = array(f, fp + "points", {-1}, PuppetArray::DType::Int64);
    part.points = Eigen::Map<const VectorXi>(pts.i64.data(), static_cast<Index>(pts.i64.size()));
    const Index Pp = part.points.size();
    check_range<Index>("puppet " + fp + "points length", Pp, 1, P, kDamaged);
    part.mean_shape.resize(Pp, 2);
    for (Index i = 0; i < Pp; ++i) {
      const Index q = part.points(i);
      if (q < 0 || q >= P) fail_argument("puppet part ", p, " names point ", q, " of ", P);
      ++seen[static_cast<size_t>(q)];
      part.mean_shape.row(i) = mean_shape_.row(q);
    }
    part.basis = array(f, fp + "basis", {-1, 2 * Pp}).matrix();
    const Index K = part.basis.rows();
    check_range<Index>("puppet " + fp + "basis rows (face dims)", K, 1, std::min(2 * Pp, kMaxDims), kDamaged);
    const double skew = (part.basis * part.basis.transpose() - RowMatrixXd::Identity(K, K)).cwiseAbs().maxCoeff();
    if (!(skew <= 1e-6)) {
      fail_argument("puppet array '", fp, "basis' must have orthonormal rows, but B Bᵀ differs from the identity "
                    "by ", skew, "; ", kDamaged);
    }
    part.startprob = array(f, hp + "startprob", {-1}).matrix().row(0).transpose();
    const Index N = part.startprob.size();
    check_range<Index>("puppet " + hp + "startprob length (states)", N, 1, kMaxStates, kDamaged);
    part.transmat = array(f, hp + "transmat", {N, N}).matrix();
    check_array(hp + "startprob and " + hp + "transmat", [&] { make_transitions(part.startprob, part.transmat); });
    part.face_means = array(f, hp + "face_means", {N, 2 * K}).matrix();
    part.face_covars = array(f, hp + "face_covars", {N, 2 * K, 2 * K}).matrix();
    part.vocal_means = array(f, hp + "vocal_means", {N, V}).matrix();
    const double vmax = part.vocal_means.cwiseAbs().maxCoeff();
    check_range("puppet array '" + hp + "vocal_means' largest |value|", vmax, 0.0, kMaxStandardized, kDamaged);
    const PuppetArray& vc = f.at(hp + "vocal_covars");
    if (vc.shape.size() == 3) {
      part.vocal_covars = array(f, hp + "vocal_covars", {N, V, V}).matrix();
      part.vocal_type = CovarianceType::Full;
    } else {
      part.vocal_covars = array(f, hp + "vocal_covars", {N, V}).matrix();
      part.vocal_type = CovarianceType::Diagonal;
    }
    check_array(hp + "vocal_covars", [&] { check_covariances(part.vocal_covars, N, V, part.vocal_type); });
    check_array(hp + "face_covars", [&] {
      native_.emplace_back(part.face_means.leftCols(K), part.face_means.rightCols(K), part.face_covars,
                           CovarianceType::Full, 1.0);
    });
    parts_.push_back(std::move(part));
  }
  if (parts_.empty()) fail_argument("the puppet has no face part (no array 'face/part0/points')");
  for (Index q = 0; q < P; ++q) {
    if (seen[static_cast<size_t>(q)] != 1) {
      fail_argument("puppet parts must partition the ", P, " points; point ", q, " is in ",
                    seen[static_cast<size_t>(q)], " parts");
    }
  }
  check_state_faces();
  read_guide(A);
}

void Puppet::check_state_faces() const {
  Index col = 0;
  for (Index p = 0; p < n_parts(); ++p) {
    const PuppetPart& pt = parts_[static_cast<size_t>(p)];
    RowMatrixXd face = RowMatrixXd::Zero(pt.n_states(), n_dims());
    face.middleCols(col, pt.n_dims()) = pt.face_means.leftCols(pt.n_dims());
    col += pt.n_dims();
    const RowMatrixXd points = to_points(face);
    Index n = 0, j = 0;
    if (beyond_pixels(points, n, j)) {
      fail_argument("puppet part ", p, " state ", n, " puts point ", j / 2, " at ", points(n, j),
                    " px, outside [", -kMaxPixel, ", ", kMaxPixel, "] (face/mean_shape, face/part", p,
                    "/basis, hmm/part", p, "/face_means and face/mean_pose together); ", kDamaged);
    }
  }
}

void Puppet::check_reach(const RowMatrixXd& points) const {
  Index t = 0, j = 0;
  if (!beyond_pixels(points, t, j)) return;
  fail_argument("the animation puts point ", j / 2, " of frame ", t, " at ", points(t, j), " px, outside [",
                -kMaxPixel, ", ", kMaxPixel, "]: the features are not of the kind the puppet was trained on, "
                "or its velocity means (hmm/part*/face_means), guide (guide/map, guide/offset) or audio "
                "standardisation (audio/mean, audio/std) are damaged");
}

void Puppet::read_guide(Index n_columns) {
  const auto& f = file_;
  if (!f.arrays.count("guide/map")) {
    const auto it = f.arrays.lower_bound("guide/");
    if (it != f.arrays.end() && it->first.compare(0, 6, "guide/") == 0) {
      fail_argument("puppet array '", it->first, "' belongs to a guide but the file has no 'guide/map'; "
                    "the file is damaged or from an incompatible tool");
    }
    return;
  }
  const Index K = n_dims();
  guide_ = read_context_map(f, "guide/map", "guide/offset", "guide/context", "guide/columns", n_columns, K);
  guide_weight_ = array(f, "guide/weight", {1}).f64[0];
  if (!(guide_weight_ >= 0)) fail_argument("puppet guide/weight must be >= 0, got ", guide_weight_);
  guide_covariance_ = array(f, "guide/covariance", {K, K}).matrix();
  const Eigen::MatrixXd& r = guide_covariance_;
  const double rmax = r.cwiseAbs().maxCoeff();
  if (!((r - r.transpose()).cwiseAbs().maxCoeff() <= 1e-10 * rmax)) {
    fail_argument("puppet guide/covariance is not symmetric; the file is damaged or from an incompatible tool");
  }
  Index off = 0;
  for (const auto& pt : parts_) {
    const Index Kp = pt.n_dims();
    Eigen::MatrixXd rp = 0.5 * (r.block(off, off, Kp, Kp) + r.block(off, off, Kp, Kp).transpose());
    // relative to the mean variance; a zero block (a perfect cross-fitted prediction, e.g. a
    // motionless part) gets the floor itself: evidence that holds the part to ŷ
    const double mean_var = rp.trace() / static_cast<double>(Kp);
    const double floor = kGuideCovarianceFloor * (mean_var > 0 ? mean_var : 1.0);
    Eigen::LLT<Eigen::MatrixXd> llt(rp + floor * Eigen::MatrixXd::Identity(Kp, Kp));
    if (!(mean_var >= 0) || llt.info() != Eigen::Success) {
      fail_argument("puppet guide/covariance (rows ", off, " .. ", off + Kp - 1,
                    ") is not positive semi-definite with positive variances; the file is damaged");
    }
    Eigen::MatrixXd prec = llt.solve(Eigen::MatrixXd::Identity(Kp, Kp));
    guide_precision_.push_back(0.5 * (prec + prec.transpose()));
    off += Kp;
  }
}

Puppet Puppet::load(const std::string& path) {
  try {
    return Puppet(read_puppet_file(path));
  } catch (const std::invalid_argument& e) {
    const std::string msg = e.what();
    if (msg.find(path) != std::string::npos) throw;
    fail_argument(path, ": ", msg);
  }
}

Index Puppet::n_dims() const {
  Index k = 0;
  for (const auto& p : parts_) k += p.n_dims();
  return k;
}

const PuppetPart& Puppet::part(Index p) const {
  if (p < 0 || p >= n_parts()) fail_argument("part index ", p, " out of range [0, ", n_parts(), ")");
  return parts_[static_cast<size_t>(p)];
}

RowMatrixXd Puppet::standardize(const MatrixRef& raw) const {
  if (raw.cols() != n_features()) {
    fail_argument("audio features have ", raw.cols(), " columns but the puppet was trained on ",
                  n_features(), "; extract them with the puppet's feature set");
  }
  if (raw.rows() < 1) fail_argument("no audio feature frames (the audio is empty)");
  require_finite(raw, "audio features");
  RowMatrixXd z = append_deltas(raw, delta_width_);
  z.rowwise() -= audio_mean_.transpose();
  z.array().rowwise() /= audio_std_.transpose().array();
  Index t = 0, j = 0;
  const double reach = z.array().abs().maxCoeff(&t, &j);
  if (!(reach <= kMaxStandardized)) {
    // Beyond this no Gaussian state explains the frame (every log density is -inf): say why here
    // rather than as a "zero probability" in the decoder.
    fail_argument("audio feature ", j, " of frame ", t, " is ", reach, " standard deviations from the puppet's "
                  "training mean, beyond ", kMaxStandardized, ": the features are not of the kind the puppet was "
                  "trained on, or its audio standardisation (audio/mean, audio/std) is damaged");
  }
  return z;
}

RowMatrixXd Puppet::project(const MatrixRef& standardized) const {
  if (standardized.cols() != audio_mean_.size()) {
    fail_argument("standardised features must have ", audio_mean_.size(), " columns (Puppet::standardize), got ",
                  standardized.cols());
  }
  if (!projected()) return standardized;
  return projection_.apply(standardized);
}

RowMatrixXd Puppet::guide_predict(const MatrixRef& standardized) const {
  if (!guided()) fail_argument("the puppet has no guide (train it with guide=\"ridge\")");
  if (standardized.cols() != audio_mean_.size()) {
    fail_argument("standardised features must have ", audio_mean_.size(), " columns (Puppet::standardize), got ",
                  standardized.cols());
  }
  return guide_.apply(standardized);
}

const Eigen::MatrixXd& Puppet::guide_precision(Index p) const {
  part(p);  // validates p
  if (!guided()) fail_argument("the puppet has no guide (train it with guide=\"ridge\")");
  return guide_precision_[static_cast<size_t>(p)];
}

double Puppet::guide_lambda(double weight) const {
  if (std::isnan(weight) || weight < 0) return guide_weight_;
  if (!std::isfinite(weight)) fail_argument("guide_weight must be finite, got ", weight);
  if (weight > 0 && !guided()) {
    fail_argument("guide_weight = ", weight, " needs a guided puppet, but this one has no guide; "
                  "train it with guide=\"ridge\" or pass 0");
  }
  return weight;
}

RowMatrixXd Puppet::vocal_log_density(const MatrixRef& standardized, Index p) const {
  const PuppetPart& pt = part(p);
  if (!projected()) return gaussian_log_density(standardized, pt.vocal_means, pt.vocal_covars, pt.vocal_type);
  return gaussian_log_density(project(standardized), pt.vocal_means, pt.vocal_covars, pt.vocal_type);
}

double Puppet::out_rate(double fps) const {
  if (fps == 0) return fps_;
  check_range("output fps", fps, kMinFps, kMaxFps, "0 is the puppet's own rate");
  return fps;
}

Index Puppet::out_frames(Index n, double out) const {
  if (n < 1) fail_argument("no audio feature frames (the audio is empty)");
  check_range<Index>("audio feature frames", n, 1, kMaxFrames, "animate long audio in pieces");
  const Index m = out == fps_ ? n : resampled_length(n, fps_, out);
  check_range<Index>("output frames (" + frames_at(n, fps_) + " resampled to " + frames_at(m, out) + ")", m, 1,
                     kMaxFrames, "animate long audio in pieces, or at a lower output fps");
  return m;
}

TrajectoryModel Puppet::trajectory_model(double out_fps, Index p) const {
  const PuppetPart& pt = part(p);
  const double out = out_rate(out_fps);
  if (out == fps_) return native_[static_cast<size_t>(p)];
  const Index K = pt.n_dims();
  return TrajectoryModel(pt.face_means.leftCols(K), pt.face_means.rightCols(K), pt.face_covars,
                         CovarianceType::Full, fps_ / out);
}

RowMatrixXd Puppet::to_points(const MatrixRef& face) const {
  if (face.cols() != n_dims()) {
    fail_argument("face coordinates must have ", n_dims(), " columns, got ", face.cols());
  }
  const Index T = face.rows(), P = n_points();
  RowMatrixXd shape(T, 2 * P);
  Index col = 0;
  for (const auto& pt : parts_) {
    const Index K = pt.n_dims(), Pp = pt.points.size();
    RowMatrixXd s = face.middleCols(col, K) * pt.basis;  // T × 2P_p
    for (Index i = 0; i < Pp; ++i) {
      const Index q = pt.points(i);
      shape.col(2 * q) = s.col(2 * i).array() + pt.mean_shape(i, 0);
      shape.col(2 * q + 1) = s.col(2 * i + 1).array() + pt.mean_shape(i, 1);
    }
    col += K;
  }
  const double s = std::exp(mean_pose_(0)), c = std::cos(mean_pose_(1)) * s, n = std::sin(mean_pose_(1)) * s;
  RowMatrixXd out(T, 2 * P);
  for (Index q = 0; q < P; ++q) {
    out.col(2 * q) = c * shape.col(2 * q) - n * shape.col(2 * q + 1);
    out.col(2 * q).array() += mean_pose_(2);
    out.col(2 * q + 1) = n * shape.col(2 * q) + c * shape.col(2 * q + 1);
    out.col(2 * q + 1).array() += mean_pose_(3);
  }
  return out;
}

RowMatrixXd Puppet::guide_at(const RowMatrixXd& standardized, double out) const {
  const RowMatrixXd y = guide_.apply(standardized);
  return out == fps_ ? y : resample_weights(y, fps_, out);
}

Puppet::Analysis Puppet::analyse(const MatrixRef& raw_features, const AnimateOptions& options,
                                 bool guide) const {
  Analysis a;
  a.out = out_rate(options.fps);
  const bool adapt = options.adapt.kind != AdaptKind::None;
  if (adapt) check_adapt_options(options.adapt);
  // The vocal features (the projection of the standardised frames, if the puppet has one), once
  // for all parts; adaptation transforms them, in the space the vocal Gaussians live in.
  out_frames(raw_features.rows(), a.out);
  const RowMatrixXd z = standardize(raw_features);
  const RowMatrixXd v = project(z);
  const Index T = v.rows();
  if (guide) a.guide_y = guide_at(z, a.out);
  const VectorXi no_lengths;
  AnimateResult& r = a.result;
  r.states.resize(T, n_parts());
  for (Index p = 0; p < n_parts(); ++p) {
    const PuppetPart& pt = parts_[static_cast<size_t>(p)];
    RowMatrixXd log_b;
    if (adapt) {
      r.transforms.push_back(adapt_features(v, no_lengths, pt.vocal_means, pt.vocal_covars, pt.vocal_type,
                                            pt.startprob, pt.transmat, options.adapt));
      const FeatureTransform& tr = r.transforms.back();
      log_b = gaussian_log_density(tr.apply(v), pt.vocal_means, pt.vocal_covars, pt.vocal_type);
      r.log_likelihood += tr.log_jacobian(T);
    } else {
      log_b = gaussian_log_density(v, pt.vocal_means, pt.vocal_covars, pt.vocal_type);
    }
    ViterbiResult vit = viterbi(log_b, pt.startprob, pt.transmat, no_lengths);
    r.states.col(p) = vit.path;
    if (options.posterior) {
      ForwardBackwardResult fb = forward_backward(log_b, pt.startprob, pt.transmat, no_lengths);
      r.log_likelihood += fb.log_likelihood;
      a.posteriors.push_back(a.out == fps_ ? std::move(fb.posteriors) : resample_weights(fb.posteriors, fps_, a.out));
    } else {
      r.log_likelihood += vit.log_probability;
      a.paths.push_back(a.out == fps_ ? std::move(vit.path) : resample_states(vit.path, fps_, a.out));
    }
  }
  return a;
}

RowMatrixXd Puppet::synthesise(const Analysis& a, double lambda) const {
  Index col = 0;
  std::vector<RowMatrixXd> faces;
  for (Index p = 0; p < n_parts(); ++p) {
    const PuppetPart& pt = parts_[static_cast<size_t>(p)];
    const TrajectoryModel model = trajectory_model(a.out, p);
    TrajectoryEvidence evidence;
    const TrajectoryEvidence* ev = nullptr;
    if (lambda > 0) {  // part p's columns of ŷ, with precision λ R[sl, sl]⁻¹
      evidence.targets = a.guide_y.middleCols(col, pt.n_dims());
      evidence.precision = lambda * guide_precision_[static_cast<size_t>(p)];
      ev = &evidence;
    }
    col += pt.n_dims();
    const auto i = static_cast<size_t>(p);
    faces.push_back(a.paths.empty() ? solve_trajectory_weighted(model, a.posteriors[i], ev)
                                    : solve_trajectory(model, a.paths[i], ev));
  }
  return side_by_side(faces, n_dims());
}

AnimateResult Puppet::animate(const MatrixRef& raw_features, const AnimateOptions& options) const {
  const double lambda = guide_lambda(options.guide_weight);
  Analysis a = analyse(raw_features, options, lambda > 0);
  AnimateResult r = std::move(a.result);
  r.face = synthesise(a, lambda);
  r.points = to_points(r.face);
  check_reach(r.points);
  return r;
}

std::vector<RowMatrixXd> Puppet::animate_faces(const MatrixRef& raw_features, const std::vector<double>& guide_weights,
                                               const AnimateOptions& options) const {
  std::vector<double> lambdas;
  bool guide = false;
  for (const double w : guide_weights) {
    lambdas.push_back(guide_lambda(w));
    guide = guide || lambdas.back() > 0;
  }
  const Analysis a = analyse(raw_features, options, guide);
  std::vector<RowMatrixXd> faces;
  for (const double lambda : lambdas) faces.push_back(synthesise(a, lambda));
  return faces;
}

void Puppet::check_states(const Eigen::Ref<const IndexMatrix>& states, double states_fps, double out) const {
  check_range("states_fps", states_fps, kMinFps, kMaxFps);
  if (states.rows() < 1 || states.cols() != n_parts()) {
    fail_argument("states must have at least one frame and one column per face part (", n_parts(),
                  "), got ", shape_of(states));
  }
  for (Index p = 0; p < n_parts(); ++p) {
    const Index n = parts_[static_cast<size_t>(p)].n_states();
    if ((states.col(p).array() < 0).any() || (states.col(p).array() >= n).any()) {
      fail_argument("states of part ", p, " must lie in [0, ", n, ")");
    }
  }
  check_range<Index>("state frames", states.rows(), 1, kMaxFrames);
  const Index m = states_fps == out ? states.rows() : resampled_length(states.rows(), states_fps, out);
  check_range<Index>("output frames (" + frames_at(states.rows(), states_fps) + " of states resampled to " +
                     frames_at(m, out) + ")", m, 1, kMaxFrames, "synthesise at a lower output fps");
}

AnimateResult Puppet::animate_states(const Eigen::Ref<const IndexMatrix>& states, double states_fps,
                                     double out_fps) const {
  const double out = out_rate(out_fps);
  check_states(states, states_fps, out);
  AnimateResult r;
  r.states = states;
  std::vector<RowMatrixXd> faces;
  for (Index p = 0; p < n_parts(); ++p) {
    const VectorXi s = states.col(p);
    // The trajectory model's velocities are per training frame; states at another rate are
    // first brought to the output rate.
    faces.push_back(solve_trajectory(trajectory_model(out, p),
                                     states_fps == out ? s : resample_states(s, states_fps, out)));
  }
  r.face = side_by_side(faces, n_dims());
  r.points = to_points(r.face);
  check_reach(r.points);
  return r;
}

AnimateResult Puppet::animate_states(const Eigen::Ref<const IndexMatrix>& states, double states_fps,
                                     const MatrixRef& raw_features, const AnimateOptions& options) const {
  check_states(states, states_fps, out_rate(options.fps));
  if (options.posterior) {
    fail_argument("given states are one path: posterior-weighted synthesis does not apply to them");
  }
  if (options.adapt.kind != AdaptKind::None) {
    fail_argument("adaptation changes how the audio is decoded; given states are not decoded: drop it");
  }
  const double lambda = guide_lambda(options.guide_weight);
  Analysis a;
  a.out = out_rate(options.fps);
  const Index n_out = out_frames(raw_features.rows(), a.out);
  const RowMatrixXd z = standardize(raw_features);
  if (lambda > 0) a.guide_y = guide_at(z, a.out);
  for (Index p = 0; p < n_parts(); ++p) {
    const VectorXi s = states.col(p);
    VectorXi path = states_fps == a.out ? s : resample_states(s, states_fps, a.out);
    const Index m = path.size();
    if (std::abs(m - n_out) > 1) {
      fail_argument("the states cover ", m, " frames at ", a.out, " fps and the audio ", n_out,
                    ": give the audio the states were decoded from (or synthesise them without audio)");
    }
    if (m != n_out) {  // one frame of rounding between the two rates: hold the last state, or cut
      const Index last = path(m - 1);
      path.conservativeResize(n_out);
      if (n_out > m) path(n_out - 1) = last;
    }
    a.paths.push_back(std::move(path));
  }
  AnimateResult r;
  r.states = states;
  r.face = synthesise(a, lambda);
  r.points = to_points(r.face);
  check_reach(r.points);
  return r;
}

}  // namespace voicepuppet
