// Closed-form trajectory synthesis: block Cholesky of the block-tridiagonal normal equations
// (see trajectory.hpp for the objective and the blocks).
#include "voicepuppet/trajectory.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <vector>

namespace voicepuppet {
namespace {

using Eigen::MatrixXd;

// ------------------------------------------------------------------ packed triangular helpers
// A lower-triangular D×D factor is stored column by column, rows j..D−1 of column j.
inline Index packed_size(Index d) { return d * (d + 1) / 2; }

void pack_lower(const MatrixXd& l, double* dst) {
  const Index d = l.rows();
  for (Index j = 0; j < d; ++j) {
    const Index len = d - j;
    Eigen::Map<VectorXd>(dst, len) = l.col(j).tail(len);
    dst += len;
  }
}

// v ← L⁻¹ v
void packed_forward(const double* l, Index d, double* v) {
  for (Index j = 0; j < d; ++j) {
    const double x = v[j] / l[0];
    v[j] = x;
    const Index len = d - j - 1;
    Eigen::Map<VectorXd>(v + j + 1, len) -= x * Eigen::Map<const VectorXd>(l + 1, len);
    l += len + 1;
  }
}

// v ← L⁻ᵀ v
void packed_backward(const double* l, Index d, double* v) {
  const double* col_end = l + packed_size(d);  // one past the last column
  for (Index j = d - 1; j >= 0; --j) {
    const Index len = d - j - 1;
    const double* col = col_end - (len + 1);
    double s = v[j];
    if (len > 0) s -= Eigen::Map<const VectorXd>(col + 1, len).dot(Eigen::Map<const VectorXd>(v + j + 1, len));
    v[j] = s / col[0];
    col_end = col;
  }
}

// ------------------------------------------------------------------ small dense kernels
// Recursive splits hand most of the work to Eigen's matrix product, which is several times
// faster than its triangular solve and Cholesky at D ≈ 50 (measured: 17 → 8 µs, 7 → 4 µs).
using BlockRef = Eigen::Ref<MatrixXd, 0, Eigen::OuterStride<>>;
using ConstBlockRef = Eigen::Ref<const MatrixXd, 0, Eigen::OuterStride<>>;
constexpr Index kTrsmLeaf = 16;
constexpr Index kLltLeaf = 25;

// w ← L⁻¹ w for lower-triangular l
void lower_solve(const ConstBlockRef& l, BlockRef w) {
  const Index n = l.rows();
  if (n <= kTrsmLeaf) {
    l.triangularView<Eigen::Lower>().solveInPlace(w);
    return;
  }
  const Index h = n / 2;
  lower_solve(l.topLeftCorner(h, h), w.topRows(h));
  w.bottomRows(n - h).noalias() -= l.bottomLeftCorner(n - h, h) * w.topRows(h);
  lower_solve(l.bottomRightCorner(n - h, n - h), w.bottomRows(n - h));
}

// In-place lower Cholesky (reads the lower triangle); false if not positive definite.
bool cholesky_lower(BlockRef a) {
  const Index n = a.rows();
  if (n <= kLltLeaf) {
    Eigen::LLT<BlockRef, Eigen::Lower> llt(a);
    return llt.info() == Eigen::Success;
  }
  const Index h = n / 2;
  if (!cholesky_lower(a.topLeftCorner(h, h))) return false;
  auto l21 = a.bottomLeftCorner(n - h, h);
  a.topLeftCorner(h, h).triangularView<Eigen::Lower>().transpose().solveInPlace<Eigen::OnTheRight>(l21);
  a.bottomRightCorner(n - h, n - h).selfadjointView<Eigen::Lower>().rankUpdate(l21, -1.0);
  return cholesky_lower(a.bottomRightCorner(n - h, n - h));
}

// ------------------------------------------------------------------ argument checks
void check_states(const IndexVectorRef& states, Index n_states) {
  if (states.size() == 0) {
    fail_argument("states must hold at least one frame, got an empty sequence");
  }
  for (Index t = 0; t < states.size(); ++t) {
    if (states[t] < 0 || states[t] >= n_states) {
      fail_argument("states[", t, "] = ", states[t], " is out of range: the model has ", n_states,
                    " states (valid indices 0 .. ", n_states - 1, ")");
    }
  }
}

void check_weight_row(const double* w, Index n, Index t, const char* name) {
  double sum = 0.0;
  for (Index i = 0; i < n; ++i) {
    if (!std::isfinite(w[i]) || w[i] < 0.0) {
      fail_argument(name, "[", t, ", ", i, "] = ", w[i],
                    " is not a finite non-negative weight; pass state posteriors or probabilities");
    }
    sum += w[i];
  }
  if (!(sum > 0.0)) {
    fail_argument(name, " row ", t, " sums to zero: every frame needs a positive weight on some state");
  }
}

void check_weights(const MatrixRef& weights, Index n_states, const char* name) {
  if (weights.rows() == 0) fail_argument(name, " must hold at least one frame, got 0 rows");
  if (weights.cols() != n_states) {
    fail_argument(name, " must have ", n_states, " columns (one per state), got ", shape_of(weights));
  }
  for (Index t = 0; t < weights.rows(); ++t) check_weight_row(weights.row(t).data(), n_states, t, name);
}

[[noreturn]] void fail_singular(Index t, double cond) {
  fail_numeric("the trajectory normal equations are numerically singular at frame ", t,
               " (condition estimate ", cond, ", limit ", kTrajectoryMaxCondition,
               "); floor the model's variances (a relative variance floor) and retry");
}

// Running condition estimate: ratio of the largest to the smallest squared Cholesky pivot.
struct PivotRange {
  double lo = std::numeric_limits<double>::infinity();
  double hi = 0.0;
  void add(double p2) {
    lo = std::min(lo, p2);
    hi = std::max(hi, p2);
  }
  double cond() const { return lo > 0.0 ? hi / lo : std::numeric_limits<double>::infinity(); }
};

// Factor Q (lower) in place; throws on failure or an excessive condition estimate.
void factor_block(MatrixXd& q, Index t, PivotRange& range) {
  if (!cholesky_lower(q)) fail_singular(t, std::numeric_limits<double>::infinity());
  for (Index i = 0; i < q.rows(); ++i) range.add(q(i, i) * q(i, i));
  if (range.cond() > kTrajectoryMaxCondition) fail_singular(t, range.cond());
}

// ------------------------------------------------------------------ frame-term providers
// A provider gives, for frame t, its diagonal block (first or self), right-hand side, the
// coupling H[t−1,t] and its contribution (next, r_next) to frame t−1.
struct HardFull {
  const std::vector<TrajectoryModel::FullBlocks>& b;
  const IndexVectorRef& s;
  const MatrixXd& diag(Index t) { return t == 0 ? b[s[0]].first : b[s[t]].self; }
  const VectorXd& rhs(Index t) { return t == 0 ? b[s[0]].r_first : b[s[t]].r_self; }
  const MatrixXd& up(Index t) { return b[s[t]].up; }
  const MatrixXd& next(Index t) { return b[s[t]].next; }
  const VectorXd& r_next(Index t) { return b[s[t]].r_next; }
};

struct WeightedFull {
  const std::vector<TrajectoryModel::FullBlocks>& b;
  const MatrixRef& w;
  MatrixXd m_diag, m_up, m_next, m_up2;
  VectorXd v_rhs, v_next;
  WeightedFull(const std::vector<TrajectoryModel::FullBlocks>& blocks, const MatrixRef& weights, Index d)
      : b(blocks), w(weights), m_diag(d, d), m_up(d, d), m_next(d, d), m_up2(d, d), v_rhs(d), v_next(d) {}
  template <class T, class F>
  const T& sum(Index t, T& out, F field) {
    out.setZero();
    for (Index n = 0; n < w.cols(); ++n) {
      const double g = w(t, n);
      if (g != 0.0) out.noalias() += g * field(b[n]);
    }
    return out;
  }
  using FB = TrajectoryModel::FullBlocks;
  const MatrixXd& diag(Index t) {
    return t == 0 ? sum(t, m_diag, [](const FB& x) -> const MatrixXd& { return x.first; })
                  : sum(t, m_diag, [](const FB& x) -> const MatrixXd& { return x.self; });
  }
  const VectorXd& rhs(Index t) {
    return t == 0 ? sum(t, v_rhs, [](const FB& x) -> const VectorXd& { return x.r_first; })
                  : sum(t, v_rhs, [](const FB& x) -> const VectorXd& { return x.r_self; });
  }
  const MatrixXd& up(Index t) { return sum(t, m_up, [](const FB& x) -> const MatrixXd& { return x.up; }); }
  const MatrixXd& next(Index t) { return sum(t, m_next, [](const FB& x) -> const MatrixXd& { return x.next; }); }
  const VectorXd& r_next(Index t) {
    return sum(t, v_next, [](const FB& x) -> const VectorXd& { return x.r_next; });
  }
};

// Block Cholesky of the block-tridiagonal system, then the two triangular sweeps.
template <class Provider>
RowMatrixXd solve_full(Provider& p, Index n_frames, Index d) {
  RowMatrixXd y(n_frames, d);  // holds z_t (forward sweep) then y_t
  const Index psz = packed_size(d);
  // not zero-initialised: every entry is written by pack_lower before it is read
  std::unique_ptr<double[]> factors(new double[static_cast<size_t>(n_frames * psz)]);
  MatrixXd q(d, d), prev(d, d), w(d, d);
  VectorXd g(d), v(d);
  PivotRange range;
  for (Index t = 0; t < n_frames; ++t) {
    q = p.diag(t);
    g = p.rhs(t);
    if (t + 1 < n_frames) {
      q += p.next(t + 1);
      g += p.r_next(t + 1);
    }
    if (t > 0) {
      w = p.up(t);
      lower_solve(prev, w);  // W = L_{t−1}⁻¹ H[t−1,t]
      q.selfadjointView<Eigen::Lower>().rankUpdate(w.transpose(), -1.0);
      g.noalias() -= w.transpose() * y.row(t - 1).transpose();
    }
    factor_block(q, t, range);
    q.triangularView<Eigen::Lower>().solveInPlace(g);
    y.row(t) = g.transpose();
    pack_lower(q, factors.get() + t * psz);
    std::swap(q, prev);
  }
  // backward: y_t = L_t⁻ᵀ (z_t − L_t⁻¹ H[t,t+1] y_{t+1})
  packed_backward(factors.get() + (n_frames - 1) * psz, d, y.row(n_frames - 1).data());
  for (Index t = n_frames - 2; t >= 0; --t) {
    const double* lt = factors.get() + t * psz;
    v.noalias() = p.up(t + 1) * y.row(t + 1).transpose();
    packed_forward(lt, d, v.data());
    double* yt = y.row(t).data();
    Eigen::Map<VectorXd>(yt, d) -= v;
    packed_backward(lt, d, yt);
  }
  return y;
}

// Diagonal covariance: D independent scalar tridiagonal systems (LDLᵀ), vectorised over D.
// `terms(t, kind)` returns a pointer to the #D row of the requested term for frame t.
enum Term { kDiag = 0, kRhs, kUp, kNext, kRNext };

template <class Terms>
RowMatrixXd solve_diag(Terms& terms, Index n_frames, Index d) {
  using Arr = Eigen::Array<double, Eigen::Dynamic, 1>;
  using Map = Eigen::Map<Arr>;
  using CMap = Eigen::Map<const Arr>;
  RowMatrixXd y(n_frames, d);        // g_t, then y_t
  RowMatrixXd inv_piv(n_frames, d);  // 1 / d_t
  Arr lo = Arr::Constant(d, std::numeric_limits<double>::infinity());
  Arr hi = Arr::Zero(d);
  Arr q(d), g(d);
  for (Index t = 0; t < n_frames; ++t) {
    q = CMap(terms(t, kDiag), d);
    g = CMap(terms(t, kRhs), d);
    if (t + 1 < n_frames) {
      q += CMap(terms(t + 1, kNext), d);
      g += CMap(terms(t + 1, kRNext), d);
    }
    if (t > 0) {
      CMap up(terms(t, kUp), d);
      const Arr ratio = up * Map(inv_piv.row(t - 1).data(), d);
      q -= ratio * up;
      g -= ratio * Map(y.row(t - 1).data(), d);
    }
    if (!(q > 0.0).all() || !q.allFinite()) fail_singular(t, std::numeric_limits<double>::infinity());
    lo = lo.min(q);
    hi = hi.max(q);
    Map(inv_piv.row(t).data(), d) = q.inverse();
    Map(y.row(t).data(), d) = g;
  }
  const double cond = (hi / lo).maxCoeff();
  if (cond > kTrajectoryMaxCondition) fail_singular(n_frames - 1, cond);
  Map last(y.row(n_frames - 1).data(), d);
  last *= Map(inv_piv.row(n_frames - 1).data(), d);
  for (Index t = n_frames - 2; t >= 0; --t) {
    Map yt(y.row(t).data(), d);
    yt = (yt - CMap(terms(t + 1, kUp), d) * Map(y.row(t + 1).data(), d)) * Map(inv_piv.row(t).data(), d);
  }
  return y;
}

struct HardDiag {
  const TrajectoryModel::DiagBlocks& b;
  const IndexVectorRef& s;
  const double* operator()(Index t, Term k) const {
    const Index n = s[t];
    switch (k) {
      case kDiag: return t == 0 ? b.first.row(n).data() : b.self.row(n).data();
      case kRhs: return t == 0 ? b.r_first.row(n).data() : b.r_self.row(n).data();
      case kUp: return b.up.row(n).data();
      case kNext: return b.next.row(n).data();
      default: return b.r_next.row(n).data();
    }
  }
};

struct WeightedDiag {
  const TrajectoryModel::DiagBlocks& b;
  const MatrixRef& w;
  RowMatrixXd scratch;  // one row per term kind
  WeightedDiag(const TrajectoryModel::DiagBlocks& blocks, const MatrixRef& weights, Index d)
      : b(blocks), w(weights), scratch(5, d) {}
  const double* operator()(Index t, Term k) {
    const RowMatrixXd* src = nullptr;
    switch (k) {
      case kDiag: src = t == 0 ? &b.first : &b.self; break;
      case kRhs: src = t == 0 ? &b.r_first : &b.r_self; break;
      case kUp: src = &b.up; break;
      case kNext: src = &b.next; break;
      default: src = &b.r_next; break;
    }
    scratch.row(k).noalias() = w.row(t) * (*src);
    return scratch.row(k).data();
  }
};

std::vector<TrajectoryModel::FullBlocks> expand_diag(const TrajectoryModel& model) {
  const auto& b = model.diag_blocks();
  std::vector<TrajectoryModel::FullBlocks> out(static_cast<size_t>(model.n_states()));
  for (Index n = 0; n < model.n_states(); ++n) {
    auto& f = out[n];
    f.self = b.self.row(n).transpose().asDiagonal();
    f.first = b.first.row(n).transpose().asDiagonal();
    f.next = b.next.row(n).transpose().asDiagonal();
    f.up = b.up.row(n).transpose().asDiagonal();
    f.r_self = b.r_self.row(n).transpose();
    f.r_first = b.r_first.row(n).transpose();
    f.r_next = b.r_next.row(n).transpose();
  }
  return out;
}

}  // namespace

// ------------------------------------------------------------------ the model
TrajectoryModel::TrajectoryModel(const MatrixRef& means, const MatrixRef& vel_means,
                                 const MatrixRef& covars, CovarianceType type, double velocity_scale)
    : n_states_(means.rows()), n_dims_(means.cols()), type_(type), velocity_scale_(velocity_scale) {
  const Index n = n_states_, d = n_dims_;
  if (n == 0 || d == 0) {
    fail_argument("means must be #states by #dims with both at least 1, got ", shape_of(means));
  }
  if (vel_means.rows() != n || vel_means.cols() != d) {
    fail_argument("vel_means must have the shape of means (", n, " x ", d, "), got ", shape_of(vel_means));
  }
  require_finite(means, "means");
  require_finite(vel_means, "vel_means");
  if (!std::isfinite(velocity_scale) || velocity_scale <= 0.0) {
    fail_argument("velocity_scale must be a finite positive ratio f_model / f_out, got ", velocity_scale);
  }
  const double r = velocity_scale;
  if (type == CovarianceType::Diagonal) {
    if (covars.rows() != n || covars.cols() != 2 * d) {
      fail_argument("covars (diagonal) must be ", n, " x ", 2 * d,
                    " ([pose, velocity] variances per state), got ", shape_of(covars));
    }
    require_finite(covars, "covars");
    for (Index i = 0; i < n; ++i) {
      for (Index j = 0; j < 2 * d; ++j) {
        if (!(covars(i, j) > 0.0)) {
          fail_argument("covars[", i, ", ", j, "] = ", covars(i, j),
                        " must be a positive variance; apply a variance floor");
        }
      }
    }
    const RowMatrixXd a = covars.leftCols(d).cwiseInverse();
    const RowMatrixXd c = (covars.rightCols(d) * (r * r)).cwiseInverse();
    const RowMatrixXd mudot = vel_means * r;
    diag_.self = a + c;
    diag_.first = a;
    diag_.next = c;
    diag_.up = -c;
    diag_.r_self = a.cwiseProduct(means) + c.cwiseProduct(mudot);
    diag_.r_first = a.cwiseProduct(means);
    diag_.r_next = -c.cwiseProduct(mudot);
    return;
  }
  if (covars.rows() != n * 2 * d || covars.cols() != 2 * d) {
    fail_argument("covars (full) must be ", n * 2 * d, " x ", 2 * d,
                  " (a C-contiguous [N, 2D, 2D] array of [pose, velocity] covariances reshaped), got ",
                  shape_of(covars));
  }
  require_finite(covars, "covars");
  full_.resize(static_cast<size_t>(n));
  const Index d2 = 2 * d;
  Eigen::VectorXd scale(d2);
  scale.head(d).setOnes();
  scale.tail(d).setConstant(r);
  for (Index i = 0; i < n; ++i) {
    const MatrixXd k = covars.middleRows(i * d2, d2);
    const double kmax = k.cwiseAbs().maxCoeff();
    if (!((k - k.transpose()).cwiseAbs().maxCoeff() <= 1e-10 * kmax)) {
      fail_argument("covars for state ", i, " (rows ", i * d2, " .. ", i * d2 + d2 - 1,
                    ") is not symmetric; symmetrise it ((K + K^T) / 2)");
    }
    // change of variables to output-frame velocities: K' = S K S, S = diag(1, r)
    const MatrixXd ks = scale.asDiagonal() * (0.5 * (k + k.transpose())) * scale.asDiagonal();
    Eigen::LLT<MatrixXd> llt(ks);
    double cond = std::numeric_limits<double>::infinity();
    if (llt.info() == Eigen::Success) {
      const VectorXd piv = llt.matrixLLT().diagonal().cwiseAbs2();
      cond = piv.maxCoeff() / piv.minCoeff();
    }
    if (!(cond <= kTrajectoryMaxCondition)) {
      fail_argument("covars for state ", i, " is not positive definite (condition estimate ", cond,
                    ", limit ", kTrajectoryMaxCondition, "); apply a variance floor");
    }
    // L⁻¹ from the state's own factor; precision P = L⁻ᵀ L⁻¹, pose marginal precision from L11.
    MatrixXd linv = MatrixXd::Identity(d2, d2);
    llt.matrixL().solveInPlace(linv);
    MatrixXd p = linv.transpose() * linv;
    p = 0.5 * (p + p.transpose()).eval();
    const MatrixXd l11inv = linv.topLeftCorner(d, d);
    MatrixXd a0 = l11inv.transpose() * l11inv;
    a0 = 0.5 * (a0 + a0.transpose()).eval();
    const auto A = p.topLeftCorner(d, d);
    const auto B = p.topRightCorner(d, d);
    const auto C = p.bottomRightCorner(d, d);
    const VectorXd mu = means.row(i).transpose();
    const VectorXd mudot = vel_means.row(i).transpose() * r;
    FullBlocks& f = full_[i];
    f.self = A + B + B.transpose() + C;
    f.self = 0.5 * (f.self + f.self.transpose()).eval();
    f.first = a0;
    f.next = C;
    f.up = -(B.transpose() + C);
    f.r_self = (A + B.transpose()) * mu + (B + C) * mudot;
    f.r_first = a0 * mu;
    f.r_next = -(B.transpose() * mu + C * mudot);
  }
}

// ------------------------------------------------------------------ batch solves
RowMatrixXd solve_trajectory(const TrajectoryModel& model, const IndexVectorRef& states) {
  check_states(states, model.n_states());
  if (model.covariance_type() == CovarianceType::Diagonal) {
    HardDiag terms{model.diag_blocks(), states};
    return solve_diag(terms, states.size(), model.n_dims());
  }
  HardFull p{model.full_blocks(), states};
  return solve_full(p, states.size(), model.n_dims());
}

RowMatrixXd solve_trajectory_weighted(const TrajectoryModel& model, const MatrixRef& weights) {
  check_weights(weights, model.n_states(), "weights");
  if (model.covariance_type() == CovarianceType::Diagonal) {
    WeightedDiag terms(model.diag_blocks(), weights, model.n_dims());
    return solve_diag(terms, weights.rows(), model.n_dims());
  }
  WeightedFull p(model.full_blocks(), weights, model.n_dims());
  return solve_full(p, weights.rows(), model.n_dims());
}

// ------------------------------------------------------------------ resampling
namespace {
void check_rates(double fps_in, double fps_out) {
  if (!std::isfinite(fps_in) || fps_in <= 0.0) fail_argument("fps_in must be a positive frame rate, got ", fps_in);
  if (!std::isfinite(fps_out) || fps_out <= 0.0) fail_argument("fps_out must be a positive frame rate, got ", fps_out);
}
// ceil(T · fps_out / fps_in), tolerant to rounding of an exact ratio.
Index resampled_length(Index n, double fps_in, double fps_out) {
  const double x = static_cast<double>(n) * fps_out / fps_in;
  return std::max<Index>(1, static_cast<Index>(std::ceil(x - 1e-9 * std::max(1.0, x))));
}
}  // namespace

VectorXi resample_states(const IndexVectorRef& states, double fps_in, double fps_out) {
  check_rates(fps_in, fps_out);
  if (states.size() == 0) fail_argument("states must hold at least one frame, got an empty sequence");
  const Index n = states.size();
  const Index m = resampled_length(n, fps_in, fps_out);
  VectorXi out(m);
  for (Index k = 0; k < m; ++k) {
    const double u = static_cast<double>(k) * fps_in / fps_out;
    Index j = static_cast<Index>(std::floor(u + 1e-9 * std::max(1.0, u)));
    out[k] = states[std::min(j, n - 1)];
  }
  return out;
}

RowMatrixXd resample_weights(const MatrixRef& weights, double fps_in, double fps_out) {
  check_rates(fps_in, fps_out);
  if (weights.rows() == 0 || weights.cols() == 0) {
    fail_argument("weights must be #frames by #states with both at least 1, got ", shape_of(weights));
  }
  require_finite(weights, "weights");
  const Index n = weights.rows();
  const Index m = resampled_length(n, fps_in, fps_out);
  RowMatrixXd out(m, weights.cols());
  for (Index k = 0; k < m; ++k) {
    const double u = std::min(static_cast<double>(k) * fps_in / fps_out, static_cast<double>(n - 1));
    const Index j = std::min(static_cast<Index>(std::floor(u)), n - 1);
    const double f = u - static_cast<double>(j);
    if (j + 1 < n && f > 0.0) {
      out.row(k) = (1.0 - f) * weights.row(j) + f * weights.row(j + 1);
    } else {
      out.row(k) = weights.row(j);
    }
  }
  return out;
}

// ------------------------------------------------------------------ fixed-lag streaming
FixedLagTrajectory::FixedLagTrajectory(const TrajectoryModel& model, Index lag)
    : model_(model), lag_(lag) {
  if (lag < 0) fail_argument("lag must be a non-negative number of frames, got ", lag);
  blocks_ = model.covariance_type() == CovarianceType::Diagonal ? expand_diag(model) : model.full_blocks();
  const Index d = model.n_dims();
  dg_.resize(d, d);
  next_.resize(d, d);
  up_.resize(d, d);
  rh_.resize(d);
  rnext_.resize(d);
  ring_.resize(static_cast<size_t>(lag + 2));
  for (auto& s : ring_) {
    s.qpart.resize(d, d);
    s.lc.resize(d, d);
    s.up.resize(d, d);
    s.gpart.resize(d);
    s.z.resize(d);
  }
}

FixedLagTrajectory::Slot& FixedLagTrajectory::slot(Index t) { return ring_[static_cast<size_t>(t % (lag_ + 2))]; }

void FixedLagTrajectory::push_frame(const double* w, Index state, std::vector<VectorXd>& out) {
  const Index j = pushed_;
  const Index d = model_.n_dims();
  // this frame's terms
  if (w == nullptr) {
    const auto& b = blocks_[state];
    dg_ = j == 0 ? b.first : b.self;
    rh_ = j == 0 ? b.r_first : b.r_self;
    up_ = b.up;
    next_ = b.next;
    rnext_ = b.r_next;
  } else {
    dg_.setZero();
    rh_.setZero();
    up_.setZero();
    next_.setZero();
    rnext_.setZero();
    for (Index n = 0; n < model_.n_states(); ++n) {
      if (w[n] == 0.0) continue;
      const auto& b = blocks_[n];
      dg_.noalias() += w[n] * (j == 0 ? b.first : b.self);
      rh_.noalias() += w[n] * (j == 0 ? b.r_first : b.r_self);
      up_.noalias() += w[n] * b.up;
      next_.noalias() += w[n] * b.next;
      rnext_.noalias() += w[n] * b.r_next;
    }
  }
  Slot& cur = slot(j);
  if (j > 0) {  // the previous frame's block is complete now that its successor is known
    Slot& prev = slot(j - 1);
    prev.lc = prev.qpart + next_;
    prev.z = prev.gpart + rnext_;
    Eigen::LLT<Eigen::Ref<Eigen::MatrixXd>, Eigen::Lower> llt(prev.lc);
    if (llt.info() != Eigen::Success) fail_singular(j - 1, std::numeric_limits<double>::infinity());
    prev.lc.triangularView<Eigen::Lower>().solveInPlace(prev.z);
    Eigen::MatrixXd wm = up_;
    prev.lc.triangularView<Eigen::Lower>().solveInPlace(wm);
    cur.qpart = dg_;
    cur.qpart.noalias() -= wm.transpose() * wm;
    cur.gpart = rh_;
    cur.gpart.noalias() -= wm.transpose() * prev.z;
  } else {
    cur.qpart = dg_;
    cur.gpart = rh_;
  }
  cur.up = up_;
  pushed_ = j + 1;
  (void)d;
  if (j >= lag_) emit_back_to(j - lag_, false, out);
}

void FixedLagTrajectory::emit_back_to(Index first, bool whole, std::vector<VectorXd>& out) {
  // Solve the system truncated at the last pushed frame j, back to frame `first`; emit frame
  // `first` only, or (whole) every frame first .. j.
  const Index j = pushed_ - 1;
  const Index d = model_.n_dims();
  Slot& last = slot(j);
  Eigen::MatrixXd ltr = last.qpart;
  Eigen::LLT<Eigen::Ref<Eigen::MatrixXd>, Eigen::Lower> llt(ltr);
  if (llt.info() != Eigen::Success) fail_singular(j, std::numeric_limits<double>::infinity());
  VectorXd y = last.gpart;
  ltr.triangularView<Eigen::Lower>().solveInPlace(y);
  ltr.triangularView<Eigen::Lower>().transpose().solveInPlace(y);
  std::vector<VectorXd> back;
  if (whole) back.push_back(y);
  VectorXd v(d);
  for (Index k = j - 1; k >= first; --k) {
    Slot& s = slot(k);
    v.noalias() = slot(k + 1).up * y;
    s.lc.triangularView<Eigen::Lower>().solveInPlace(v);
    y = s.z - v;
    s.lc.triangularView<Eigen::Lower>().transpose().solveInPlace(y);
    if (whole) back.push_back(y);
  }
  if (whole) {
    for (auto it = back.rbegin(); it != back.rend(); ++it) out.push_back(*it);
  } else {
    out.push_back(y);
  }
  emitted_ = whole ? j + 1 : first + 1;
}

namespace {
RowMatrixXd stack_rows(const std::vector<VectorXd>& rows, Index d) {
  RowMatrixXd out(static_cast<Index>(rows.size()), d);
  for (size_t i = 0; i < rows.size(); ++i) out.row(static_cast<Index>(i)) = rows[i].transpose();
  return out;
}
}  // namespace

RowMatrixXd FixedLagTrajectory::push_states(const IndexVectorRef& states) {
  for (Index t = 0; t < states.size(); ++t) {
    if (states[t] < 0 || states[t] >= model_.n_states()) {
      fail_argument("states[", t, "] = ", states[t], " is out of range: the model has ", model_.n_states(),
                    " states (valid indices 0 .. ", model_.n_states() - 1, "); nothing was pushed");
    }
  }
  std::vector<VectorXd> out;
  for (Index t = 0; t < states.size(); ++t) push_frame(nullptr, states[t], out);
  return stack_rows(out, model_.n_dims());
}

RowMatrixXd FixedLagTrajectory::push_weights(const MatrixRef& weights) {
  if (weights.cols() != model_.n_states()) {
    fail_argument("weights must have ", model_.n_states(), " columns (one per state), got ", shape_of(weights));
  }
  for (Index t = 0; t < weights.rows(); ++t) check_weight_row(weights.row(t).data(), model_.n_states(), t, "weights");
  std::vector<VectorXd> out;
  for (Index t = 0; t < weights.rows(); ++t) push_frame(weights.row(t).data(), 0, out);
  return stack_rows(out, model_.n_dims());
}

RowMatrixXd FixedLagTrajectory::flush() {
  std::vector<VectorXd> out;
  if (pushed_ > emitted_) emit_back_to(emitted_, true, out);
  pushed_ = 0;
  emitted_ = 0;
  return stack_rows(out, model_.n_dims());
}

}  // namespace voicepuppet
