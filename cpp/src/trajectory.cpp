// Closed-form trajectory synthesis: block Cholesky of the block-tridiagonal normal equations
// (see trajectory.hpp for the objective and the blocks).
#include "voicepuppet/trajectory.hpp"
#include "voicepuppet/interrupt.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#if defined(__AVX__)
#include <immintrin.h>
#endif

namespace voicepuppet {
namespace {

using Eigen::MatrixXd;

// ------------------------------------------------------------------ small dense kernels
// The full-covariance solve spends its time in updates of ~100×8 column panels and in small
// triangular solves. Built from Eigen's dynamic-size product, triangular solve and Cholesky per
// 50×50 block it took 28–36 µs per frame at D = 50; these kernels, in place on column-major
// arrays with a register tile of up to 24 rows × 8 columns, take 7–9 µs (docs/trajectory.md).
// They use the GCC/Clang vector extension (8 doubles: one AVX-512 register, two AVX2 or four
// SSE2 registers, whatever -march allows).
#if !defined(__GNUC__)
#error "trajectory.cpp needs the GCC/Clang vector extension (vector_size); build with GCC or Clang"
#endif
// The vector type never crosses a non-inlined call; GCC reports -Wpsabi at the end of the unit,
// so the warning is off for the whole file.
#pragma GCC diagnostic ignored "-Wpsabi"
typedef double Vec8 __attribute__((vector_size(64)));
typedef double Vec8u __attribute__((vector_size(64), aligned(8), __may_alias__));
inline Vec8 load8(const double* p) { return *reinterpret_cast<const Vec8u*>(p); }
inline void store8(double* p, Vec8 v) { *reinterpret_cast<Vec8u*>(p) = v; }
constexpr Index kBlock = 8;  // column block width (one vector)

// C[0 : 8·MR, 0 : NB] −= A[0 : 8·MR, 0 : k] · B[0 : NB, 0 : k]ᵀ (column-major, leading dims lda...)
template <int MR, int NB>
inline void tile_update(double* c, Index ldc, const double* a, Index lda, const double* b, Index ldb, Index k) {
  Vec8 acc[MR][NB];
  #pragma GCC unroll 8
  for (int r = 0; r < MR; ++r)
    #pragma GCC unroll 8
    for (int j = 0; j < NB; ++j) acc[r][j] = Vec8{};
  for (Index p = 0; p < k; ++p) {
    Vec8 av[MR];
    #pragma GCC unroll 8
    for (int r = 0; r < MR; ++r) av[r] = load8(a + p * lda + 8 * r);
    const double* bp = b + p * ldb;
    #pragma GCC unroll 8
    for (int j = 0; j < NB; ++j) {
      const double bj = bp[j];
      #pragma GCC unroll 8
      for (int r = 0; r < MR; ++r) acc[r][j] += av[r] * bj;
    }
  }
  #pragma GCC unroll 8
  for (int j = 0; j < NB; ++j)
    #pragma GCC unroll 8
    for (int r = 0; r < MR; ++r) store8(c + j * ldc + 8 * r, load8(c + j * ldc + 8 * r) - acc[r][j]);
}

// C[0 : m, 0 : NB] −= A[0 : m, 0 : k] · B[0 : NB, 0 : k]ᵀ, m rounded up to a multiple of 8: the
// arrays must have (finite) padding rows below row m.
template <int NB>
void panel_update(double* c, Index ldc, const double* a, Index lda, const double* b, Index ldb, Index m, Index k) {
  if (k == 0 || m <= 0) return;
  Index i = 0;
  for (; i + 24 <= m; i += 24) tile_update<3, NB>(c + i, ldc, a + i, lda, b, ldb, k);
  const Index rem = m - i;
  if (rem > 16) {
    tile_update<3, NB>(c + i, ldc, a + i, lda, b, ldb, k);
  } else if (rem > 8) {
    tile_update<2, NB>(c + i, ldc, a + i, lda, b, ldb, k);
  } else if (rem > 0) {
    tile_update<1, NB>(c + i, ldc, a + i, lda, b, ldb, k);
  }
}

// P[r0 : r1, 0 : NB] ← P[r0 : r1, 0 : NB] · L⁻ᵀ for the NB×NB lower factor L = P[0 : NB, 0 : NB]
// (offset by j0 rows) with reciprocal pivots rinv; r1 − r0 rounded up to a multiple of 8.
template <int NB>
void panel_trsm(double* p, Index ld, Index j0, Index r0, Index r1, const double* rinv) {
  const double* l = p + j0;  // L(i, k) = l[i + k·ld]
  for (Index i = r0; i < r1; i += 8) {
    Vec8 c[NB];
    #pragma GCC unroll 8
    for (int j = 0; j < NB; ++j) c[j] = load8(p + j * ld + i);
    #pragma GCC unroll 8
    for (int j = 0; j < NB; ++j) {
      #pragma GCC unroll 8
      for (int k = 0; k < j; ++k) c[j] -= c[k] * l[j + k * ld];
      c[j] *= rinv[j];
    }
    #pragma GCC unroll 8
    for (int j = 0; j < NB; ++j) store8(p + j * ld + i, c[j]);
  }
}

// The factorisation of one frame, in a column-major panel of 2D + 2 rows (see solve_full):
// column block [j0, j0 + NB) is updated by the previous frame's rows and by this frame's earlier
// columns, then factored (diagonal block) and solved (rows below it). Returns false on a
// non-positive or non-finite pivot; pivots (squared diagonal entries) go to lo/hi.
template <int NB>
bool factor_column_block(double* cur, const double* prev, Index ld, Index d, Index j0, double& lo, double& hi) {
  double* cj = cur + j0 * ld;
  if (prev != nullptr) panel_update<NB>(cj + j0, ld, prev + d + 1 + j0, ld, prev + d + 1 + j0, ld, d + 1 - j0, d);
  panel_update<NB>(cj + j0, ld, cur + j0, ld, cur + j0, ld, 2 * d + 1 - j0, j0);
  double rinv[NB];
  #pragma GCC unroll 8
  for (int j = 0; j < NB; ++j) {
    double* colj = cj + j * ld + j0;
    const double piv = colj[j];
    if (!(piv > 0.0) || !std::isfinite(piv)) return false;
    lo = std::min(lo, piv);
    hi = std::max(hi, piv);
    const double l = std::sqrt(piv);
    const double r = l * (1.0 / piv);  // 1 / l, the division not waiting for the square root
    rinv[j] = r;
    colj[j] = l;
    #pragma GCC unroll 8
    for (int i = j + 1; i < NB; ++i) colj[i] *= r;
    #pragma GCC unroll 8
    for (int k = j + 1; k < NB; ++k) {
      double* colk = cj + k * ld + j0;
      const double f = colj[k];
      #pragma GCC unroll 8
      for (int i = k; i < NB; ++i) colk[i] -= colj[i] * f;
    }
  }
  panel_trsm<NB>(cj, ld, j0, j0 + NB, 2 * d + 1, rinv);
  return true;
}

bool factor_block_dispatch(double* cur, const double* prev, Index ld, Index d, Index j0, double& lo, double& hi) {
  switch (std::min(kBlock, d - j0)) {
    case 1: return factor_column_block<1>(cur, prev, ld, d, j0, lo, hi);
    case 2: return factor_column_block<2>(cur, prev, ld, d, j0, lo, hi);
    case 3: return factor_column_block<3>(cur, prev, ld, d, j0, lo, hi);
    case 4: return factor_column_block<4>(cur, prev, ld, d, j0, lo, hi);
    case 5: return factor_column_block<5>(cur, prev, ld, d, j0, lo, hi);
    case 6: return factor_column_block<6>(cur, prev, ld, d, j0, lo, hi);
    case 7: return factor_column_block<7>(cur, prev, ld, d, j0, lo, hi);
    default: return factor_column_block<8>(cur, prev, ld, d, j0, lo, hi);
  }
}

// ------------------------------------------------------------------ packed factors
// A frame's lower-triangular D×D factor is stored column by column, rows j..D−1 of column j,
// with the reciprocal 1 / l_jj in place of each diagonal entry (the sweeps only multiply by it).
// Frames are `stride` doubles apart (a multiple of 8, so each starts on a 64-byte line).
class PackedFactor {
 public:
  explicit PackedFactor(Index d) : d_(d), off_(static_cast<size_t>(d + 1)) {
    for (Index j = 0; j <= d; ++j) off_[j] = j * d - j * (j - 1) / 2;
  }
  Index size() const { return off_[d_]; }
  Index stride() const { return (size() + 7) / 8 * 8; }
  // column j of the factor at l, indexed by row: col(l, j)[i] = L(i, j) for i ≥ j
  const double* col(const double* l, Index j) const { return l + off_[j] - j; }
  double* col(double* l, Index j) const { return l + off_[j] - j; }

  // x ← L⁻¹ x
  void lower_solve(const double* l, double* x) const {
    for (Index j0 = 0; j0 < d_; j0 += kBlock) {
      if (d_ - j0 >= kBlock) {
        lower_block<kBlock>(l, x, j0);
      } else {
        lower_tail(l, x, j0, d_ - j0);
      }
    }
  }

  // x ← L⁻ᵀ x
  void upper_solve(const double* l, double* x) const {
    const Index last = (d_ - 1) / kBlock * kBlock;
    if (d_ - last < kBlock) {
      upper_tail(l, x, last, d_ - last);
    } else {
      upper_block<kBlock>(l, x, last);
    }
    for (Index j0 = last - kBlock; j0 >= 0; j0 -= kBlock) upper_block<kBlock>(l, x, j0);
  }

 private:
  // block [j0, j0 + NB) of L⁻¹ x: the triangle in registers, then the rows below by vectors
  template <int NB>
  void lower_block(const double* l, double* x, Index j0) const {
    const double* c[NB];
    double xs[NB];
    #pragma GCC unroll 8
    for (int j = 0; j < NB; ++j) {
      c[j] = col(l, j0 + j);
      xs[j] = x[j0 + j];
    }
    #pragma GCC unroll 8
    for (int j = 0; j < NB; ++j) {
      xs[j] *= c[j][j0 + j];
      #pragma GCC unroll 8
      for (int i = j + 1; i < NB; ++i) xs[i] -= xs[j] * c[j][j0 + i];
    }
    #pragma GCC unroll 8
    for (int j = 0; j < NB; ++j) x[j0 + j] = xs[j];
    below_update<NB>(c, xs, x, j0 + NB);
  }
  template <int NB>
  void below_update(const double* const* c, const double* xs, double* x, Index r0) const {
    Index i = r0;
    for (; i + 8 <= d_; i += 8) {
      Vec8 acc = load8(x + i);
      #pragma GCC unroll 8
      for (int j = 0; j < NB; ++j) acc -= load8(c[j] + i) * xs[j];
      store8(x + i, acc);
    }
    for (; i < d_; ++i) {
      double s = x[i];
      #pragma GCC unroll 8
      for (int j = 0; j < NB; ++j) s -= c[j][i] * xs[j];
      x[i] = s;
    }
  }
  void lower_tail(const double* l, double* x, Index j0, Index w) const {
    for (Index j = 0; j < w; ++j) {
      const double* c = col(l, j0 + j);
      x[j0 + j] *= c[j0 + j];
      for (Index i = j + 1; i < w; ++i) x[j0 + i] -= x[j0 + j] * c[j0 + i];
    }
  }

  // block [j0, j0 + NB) of L⁻ᵀ x (the rows below it are final): NB dot products, then the triangle
  template <int NB>
  void upper_block(const double* l, double* x, Index j0) const {
    const double* c[NB];
    #pragma GCC unroll 8
    for (int j = 0; j < NB; ++j) c[j] = col(l, j0 + j);
    Vec8 acc[NB];
    #pragma GCC unroll 8
    for (int j = 0; j < NB; ++j) acc[j] = Vec8{};
    Index i = j0 + NB;
    for (; i + 8 <= d_; i += 8) {
      const Vec8 xv = load8(x + i);
      #pragma GCC unroll 8
      for (int j = 0; j < NB; ++j) acc[j] += load8(c[j] + i) * xv;
    }
    double xs[NB];
    #pragma GCC unroll 8
    for (int j = 0; j < NB; ++j) {
      double s = 0.0;
      for (Index k = i; k < d_; ++k) s += c[j][k] * x[k];
      #pragma GCC unroll 8
      for (int k = 0; k < 8; ++k) s += acc[j][k];
      xs[j] = x[j0 + j] - s;
    }
    #pragma GCC unroll 8
    for (int j = NB - 1; j >= 0; --j) {
      #pragma GCC unroll 8
      for (int k = j + 1; k < NB; ++k) xs[j] -= c[j][j0 + k] * xs[k];
      xs[j] *= c[j][j0 + j];
    }
    #pragma GCC unroll 8
    for (int j = 0; j < NB; ++j) x[j0 + j] = xs[j];
  }
  void upper_tail(const double* l, double* x, Index j0, Index w) const {  // the last block: nothing below
    for (Index j = w - 1; j >= 0; --j) {
      const double* c = col(l, j0 + j);
      double s = x[j0 + j];
      for (Index k = j + 1; k < w; ++k) s -= c[j0 + k] * x[j0 + k];
      x[j0 + j] = s * c[j0 + j];
    }
  }

  Index d_;
  std::vector<Index> off_;
};

// Writes n (a multiple of 8) doubles from src to the 64-byte aligned dst, bypassing the caches
// where the target has streaming stores: the factor store is written once and read back only
// after the whole forward pass, so caching it would only cost the reads of its old contents.
inline void stream_copy(const double* src, double* dst, Index n) {
#if defined(__AVX512F__)
  for (Index i = 0; i < n; i += 8) _mm512_stream_pd(dst + i, _mm512_loadu_pd(src + i));
#elif defined(__AVX__)
  for (Index i = 0; i < n; i += 4) _mm256_stream_pd(dst + i, _mm256_loadu_pd(src + i));
#else
  std::copy_n(src, n, dst);
#endif
}
inline void stream_fence() {
#if defined(__AVX__)
  _mm_sfence();
#endif
}

// The factor store of a solve (one packed factor per frame, T·D(D+1)/2 doubles) is its one large
// allocation; fresh pages cost a page fault each on first touch, which on a virtual machine is
// as slow as the factorisation itself. Each thread keeps its last store, up to
// kKeptStoreBytes, for its next solve; larger stores are returned to the system after the call.
constexpr size_t kKeptStoreBytes = size_t(256) << 20;

class FactorStore {
 public:
  explicit FactorStore(size_t n) {
    n += 8;
    Cache& c = cache();
    if (c.capacity >= n) {
      data_ = std::move(c.data);
      capacity_ = c.capacity;
      c.capacity = 0;
    } else {
      data_.reset(new double[n]);  // not zero-initialised: every entry is written before it is read
      capacity_ = n;
    }
  }
  ~FactorStore() {
    Cache& c = cache();
    if (capacity_ * sizeof(double) <= kKeptStoreBytes && capacity_ > c.capacity) {
      c.data = std::move(data_);
      c.capacity = capacity_;
    }
  }
  FactorStore(const FactorStore&) = delete;
  FactorStore& operator=(const FactorStore&) = delete;
  /// 64-byte aligned start (n + 8 doubles are allocated)
  double* get() {
    return reinterpret_cast<double*>((reinterpret_cast<std::uintptr_t>(data_.get()) + 63) & ~std::uintptr_t(63));
  }

 private:
  struct Cache {
    std::unique_ptr<double[]> data;
    size_t capacity = 0;
  };
  static Cache& cache() {
    thread_local Cache c;
    return c;
  }
  std::unique_ptr<double[]> data_;
  size_t capacity_ = 0;
};

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

// ------------------------------------------------------------------ frame-term providers
// A provider gives, for frame t, its diagonal block (first or self), right-hand side, the
// coupling H[t−1,t] and its contribution (next, r_next) to frame t−1.
struct HardFull {
  const std::vector<TrajectoryModel::FullBlocks>& b;
  const IndexVectorRef& s;
  const MatrixXd& diag(Index t) { return t == 0 ? b[s[0]].first : b[s[t]].self; }
  const VectorXd& rhs(Index t) { return t == 0 ? b[s[0]].r_first : b[s[t]].r_self; }
  const MatrixXd& up(Index t) { return b[s[t]].up; }
  const MatrixXd& up_t(Index t) { return b[s[t]].up_t; }
  const MatrixXd& next(Index t) { return b[s[t]].next; }
  const VectorXd& r_next(Index t) { return b[s[t]].r_next; }
};

struct WeightedFull {
  const std::vector<TrajectoryModel::FullBlocks>& b;
  const MatrixRef& w;
  MatrixXd m_diag, m_up, m_up_t, m_next;
  VectorXd v_rhs, v_next;
  WeightedFull(const std::vector<TrajectoryModel::FullBlocks>& blocks, const MatrixRef& weights, Index d)
      : b(blocks), w(weights), m_diag(d, d), m_up(d, d), m_up_t(d, d), m_next(d, d), v_rhs(d), v_next(d) {}
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
  const MatrixXd& up_t(Index t) { return sum(t, m_up_t, [](const FB& x) -> const MatrixXd& { return x.up_t; }); }
  const MatrixXd& next(Index t) { return sum(t, m_next, [](const FB& x) -> const MatrixXd& { return x.next; }); }
  const VectorXd& r_next(Index t) {
    return sum(t, v_next, [](const FB& x) -> const VectorXd& { return x.r_next; });
  }
};

// Block Cholesky of the block-tridiagonal system with the forward substitution fused in, then
// the backward sweep. Frame t is factored in a column-major panel of 2D + 2 rows (leading
// dimension ld, finite padding rows below): rows 0..D−1 hold H[t,t] (lower triangle) and become
// L_t; row D holds the right-hand side and becomes z_tᵀ = (L⁻¹ g)_t; rows D+1..2D hold H[t+1,t]
// and become L_{t+1,t} = H[t+1,t] L_t⁻ᵀ; row 2D+1 is a copy of z_t, so that rows D+1..2D+1 of the
// previous frame's panel are the one contiguous operand of the next frame's update. Each column
// block of the panel is updated left-looking (from the previous panel and its own earlier
// columns), so almost all flops are register-tiled panel updates.
// Evidence, if any, is the column-major precision W (ew, D×D) and the rows (W ŷ_t)ᵀ (erhs).
template <class Provider>
RowMatrixXd solve_full(Provider& p, Index n_frames, Index d, const double* ew = nullptr,
                       const RowMatrixXd* erhs = nullptr) {
  RowMatrixXd y(n_frames, d);  // holds z_t (forward) then y_t
  const Index ld = (2 * d + 2 + 7 + 7) / 8 * 8;
  std::vector<double> panels(static_cast<size_t>(2 * ld * d), 0.0);  // padding rows stay finite
  double* cur = panels.data();
  double* prev = cur + ld * d;
  const PackedFactor pf(d);
  const Index psz = pf.stride();
  FactorStore factors(static_cast<size_t>(n_frames * psz));
  std::vector<double> stage(static_cast<size_t>(psz), 0.0);  // one frame's factor, then streamed out
  double lo = std::numeric_limits<double>::infinity(), hi = 0.0;
  for (Index t = 0; t < n_frames; ++t) {
    check_interrupt();
    const MatrixXd& hd = p.diag(t);
    const VectorXd& g = p.rhs(t);
    if (t + 1 < n_frames) {
      const MatrixXd& hn = p.next(t + 1);
      const MatrixXd& low = p.up_t(t + 1);  // H[t+1, t]
      const VectorXd& gn = p.r_next(t + 1);
      for (Index j = 0; j < d; ++j) {
        double* col = cur + j * ld;
        const double* a = hd.data() + j * d;
        const double* b = hn.data() + j * d;
        for (Index i = j; i < d; ++i) col[i] = a[i] + b[i];
        col[d] = g[j] + gn[j];
        std::copy_n(low.data() + j * d, d, col + d + 1);
      }
    } else {
      for (Index j = 0; j < d; ++j) {
        double* col = cur + j * ld;
        std::copy_n(hd.data() + j * d + j, d - j, col + j);
        col[d] = g[j];
        std::fill_n(col + d + 1, d, 0.0);
      }
    }
    if (ew != nullptr) {  // the evidence of frame t: H[t,t] += W, r[t] += W ŷ_t
      for (Index j = 0; j < d; ++j) {
        double* col = cur + j * ld;
        const double* w = ew + j * d;
        for (Index i = j; i < d; ++i) col[i] += w[i];
        col[d] += (*erhs)(t, j);
      }
    }
    for (Index j0 = 0; j0 < d; j0 += kBlock) {
      if (!factor_block_dispatch(cur, t > 0 ? prev : nullptr, ld, d, j0, lo, hi)) {
        fail_singular(t, std::numeric_limits<double>::infinity());
      }
    }
    if (hi > kTrajectoryMaxCondition * lo) fail_singular(t, hi / lo);
    for (Index j = 0; j < d; ++j) {
      double* col = cur + j * ld;
      double* fj = pf.col(stage.data(), j);
      std::copy_n(col + j, d - j, fj + j);
      fj[j] = 1.0 / col[j];
      y(t, j) = col[d];
      col[2 * d + 1] = col[d];
    }
    stream_copy(stage.data(), factors.get() + t * psz, psz);
    std::swap(cur, prev);
  }
  stream_fence();
  // backward: y_t = L_t⁻ᵀ (z_t − L_t⁻¹ H[t,t+1] y_{t+1})
  VectorXd v(d);
  pf.upper_solve(factors.get() + (n_frames - 1) * psz, y.row(n_frames - 1).data());
  for (Index t = n_frames - 2; t >= 0; --t) {
    const double* lt = factors.get() + t * psz;
    if (t > 0) {  // the previous frame's factor comes from memory while this one is used
      for (Index i = 0; i < psz; i += 8) __builtin_prefetch(lt - psz + i);
    }
    v.noalias() = p.up(t + 1) * y.row(t + 1).transpose();
    pf.lower_solve(lt, v.data());
    double* yt = y.row(t).data();
    Eigen::Map<VectorXd>(yt, d) -= v;
    pf.upper_solve(lt, yt);
  }
  return y;
}

// Diagonal covariance: D independent scalar tridiagonal systems (LDLᵀ), vectorised over D.
// `terms(t, kind)` returns a pointer to the #D row of the requested term for frame t.
enum Term { kDiag = 0, kRhs, kUp, kNext, kRNext };

// Evidence, if any, is the diagonal of W (ew, #D) and the rows (W ŷ_t)ᵀ (erhs).
template <class Terms>
RowMatrixXd solve_diag(Terms& terms, Index n_frames, Index d, const double* ew = nullptr,
                       const RowMatrixXd* erhs = nullptr) {
  using Arr = Eigen::Array<double, Eigen::Dynamic, 1>;
  using Map = Eigen::Map<Arr>;
  using CMap = Eigen::Map<const Arr>;
  RowMatrixXd y(n_frames, d);        // g_t, then y_t
  RowMatrixXd inv_piv(n_frames, d);  // 1 / d_t
  Arr lo = Arr::Constant(d, std::numeric_limits<double>::infinity());
  Arr hi = Arr::Zero(d);
  Arr q(d), g(d);
  for (Index t = 0; t < n_frames; ++t) {
    check_interrupt();
    q = CMap(terms(t, kDiag), d);
    g = CMap(terms(t, kRhs), d);
    if (t + 1 < n_frames) {
      q += CMap(terms(t + 1, kNext), d);
      g += CMap(terms(t + 1, kRNext), d);
    }
    if (ew != nullptr) {
      q += CMap(ew, d);
      g += CMap(erhs->row(t).data(), d);
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
    f.up_t = f.up;
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
    // Precision P = K⁻¹ = L⁻ᵀ L⁻¹ by blocks of the state's own factor: L = [[L11, 0], [L21, L22]],
    // L⁻¹ = [[M1, 0], [X, M2]] with M1 = L11⁻¹, M2 = L22⁻¹, X = −L22⁻¹ L21 M1, so that
    // A = M1ᵀM1 + XᵀX, B = XᵀM2, C = M2ᵀM2, and the pose marginal precision (K^xx)⁻¹ = M1ᵀM1
    // (triangular inverses of D×D blocks instead of one 2D×2D solve: about half the flops).
    const MatrixXd lf = llt.matrixL();
    MatrixXd m1 = MatrixXd::Identity(d, d), m2 = MatrixXd::Identity(d, d);
    lf.topLeftCorner(d, d).triangularView<Eigen::Lower>().solveInPlace(m1);
    lf.bottomRightCorner(d, d).triangularView<Eigen::Lower>().solveInPlace(m2);
    MatrixXd x = -(lf.bottomLeftCorner(d, d) * m1.triangularView<Eigen::Lower>());
    lf.bottomRightCorner(d, d).triangularView<Eigen::Lower>().solveInPlace(x);
    auto gram = [d](const MatrixXd& m) {  // mᵀm, exactly symmetric
      MatrixXd g = MatrixXd::Zero(d, d);
      g.selfadjointView<Eigen::Lower>().rankUpdate(m.transpose());
      g.triangularView<Eigen::StrictlyUpper>() = g.transpose();
      return g;
    };
    const MatrixXd a0 = gram(m1);
    const MatrixXd C = gram(m2);
    const MatrixXd A = a0 + gram(x);
    const MatrixXd B = x.transpose() * m2.triangularView<Eigen::Lower>();
    const VectorXd mu = means.row(i).transpose();
    const VectorXd mudot = vel_means.row(i).transpose() * r;
    FullBlocks& f = full_[i];
    f.self = A + B + B.transpose() + C;
    f.self = 0.5 * (f.self + f.self.transpose()).eval();
    f.first = a0;
    f.next = C;
    f.up = -(B.transpose() + C);
    f.up_t = f.up.transpose();
    f.r_self = (A + B.transpose()) * mu + (B + C) * mudot;
    f.r_first = a0 * mu;
    f.r_next = -(B.transpose() * mu + C * mudot);
  }
}

// ------------------------------------------------------------------ batch solves
void check_trajectory_evidence(const TrajectoryEvidence& e, Index n_frames, Index n_dims, const char* name) {
  if (e.targets.rows() != n_frames || e.targets.cols() != n_dims) {
    fail_argument(name, ".targets must be ", n_frames, " x ", n_dims, " (one row per frame), got ",
                  shape_of(e.targets));
  }
  if (e.precision.rows() != n_dims || e.precision.cols() != n_dims) {
    fail_argument(name, ".precision must be ", n_dims, " x ", n_dims, ", got ", e.precision.rows(), " x ",
                  e.precision.cols());
  }
  require_finite(e.targets, (std::string(name) + ".targets").c_str());
  if (!e.precision.allFinite()) fail_argument(name, ".precision contains NaN or infinite values");
  const double wmax = e.precision.cwiseAbs().maxCoeff();
  if (!((e.precision - e.precision.transpose()).cwiseAbs().maxCoeff() <= 1e-10 * wmax)) {
    fail_argument(name, ".precision is not symmetric; symmetrise it ((W + W^T) / 2)");
  }
  if (wmax > 0.0) {
    const Eigen::SelfAdjointEigenSolver<MatrixXd> es(e.precision, Eigen::EigenvaluesOnly);
    const double lmin = es.eigenvalues().minCoeff();
    if (!(lmin >= -1e-12 * wmax)) {
      fail_argument(name, ".precision is not positive semi-definite (smallest eigenvalue ", lmin,
                    "); pass λ R⁻¹ for a positive definite covariance R");
    }
  }
}

namespace {
// The checked evidence in the form the solves take: W symmetrised (column-major) and W ŷ_t.
struct PreparedEvidence {
  MatrixXd w;
  RowMatrixXd wy;
  bool diagonal = false;  // W has no off-diagonal entry
  VectorXd wdiag;
  PreparedEvidence(const TrajectoryEvidence& e, Index n_frames, Index n_dims) {
    check_trajectory_evidence(e, n_frames, n_dims);
    w = 0.5 * (e.precision + e.precision.transpose());
    wy = e.targets * w;  // row t = (W ŷ_t)ᵀ, W symmetric
    wdiag = w.diagonal();
    diagonal = (w - MatrixXd(wdiag.asDiagonal())).cwiseAbs().maxCoeff() == 0.0;
  }
};
}  // namespace

RowMatrixXd solve_trajectory(const TrajectoryModel& model, const IndexVectorRef& states,
                             const TrajectoryEvidence* evidence) {
  check_states(states, model.n_states());
  const Index n = states.size(), d = model.n_dims();
  if (evidence == nullptr) {
    if (model.covariance_type() == CovarianceType::Diagonal) {
      HardDiag terms{model.diag_blocks(), states};
      return solve_diag(terms, n, d);
    }
    HardFull p{model.full_blocks(), states};
    return solve_full(p, n, d);
  }
  const PreparedEvidence e(*evidence, n, d);
  if (model.covariance_type() == CovarianceType::Diagonal) {
    if (e.diagonal) {
      HardDiag terms{model.diag_blocks(), states};
      return solve_diag(terms, n, d, e.wdiag.data(), &e.wy);
    }
    const auto blocks = expand_diag(model);
    HardFull p{blocks, states};
    return solve_full(p, n, d, e.w.data(), &e.wy);
  }
  HardFull p{model.full_blocks(), states};
  return solve_full(p, n, d, e.w.data(), &e.wy);
}

RowMatrixXd solve_trajectory_weighted(const TrajectoryModel& model, const MatrixRef& weights,
                                      const TrajectoryEvidence* evidence) {
  check_weights(weights, model.n_states(), "weights");
  const Index n = weights.rows(), d = model.n_dims();
  if (evidence == nullptr) {
    if (model.covariance_type() == CovarianceType::Diagonal) {
      WeightedDiag terms(model.diag_blocks(), weights, d);
      return solve_diag(terms, n, d);
    }
    WeightedFull p(model.full_blocks(), weights, d);
    return solve_full(p, n, d);
  }
  const PreparedEvidence e(*evidence, n, d);
  if (model.covariance_type() == CovarianceType::Diagonal) {
    if (e.diagonal) {
      WeightedDiag terms(model.diag_blocks(), weights, d);
      return solve_diag(terms, n, d, e.wdiag.data(), &e.wy);
    }
    const auto blocks = expand_diag(model);
    WeightedFull p(blocks, weights, d);
    return solve_full(p, n, d, e.w.data(), &e.wy);
  }
  WeightedFull p(model.full_blocks(), weights, d);
  return solve_full(p, n, d, e.w.data(), &e.wy);
}

// ------------------------------------------------------------------ resampling
namespace {
void check_rates(double fps_in, double fps_out) {
  if (!std::isfinite(fps_in) || fps_in <= 0.0) fail_argument("fps_in must be a positive frame rate, got ", fps_in);
  if (!std::isfinite(fps_out) || fps_out <= 0.0) fail_argument("fps_out must be a positive frame rate, got ", fps_out);
}
}  // namespace

Index resampled_length(Index n, double fps_in, double fps_out) {
  check_rates(fps_in, fps_out);
  const double x = static_cast<double>(n) * fps_out / fps_in;
  return std::max<Index>(1, static_cast<Index>(std::ceil(x - 1e-9 * std::max(1.0, x))));
}

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

FixedLagTrajectory::FixedLagTrajectory(const TrajectoryModel& model, Index lag, const Eigen::MatrixXd& precision)
    : FixedLagTrajectory(model, lag) {
  const Index d = model.n_dims();
  check_trajectory_evidence(TrajectoryEvidence{RowMatrixXd(0, d), precision}, 0, d, "precision");
  w_ = 0.5 * (precision + precision.transpose());
  evidence_ = true;
}

FixedLagTrajectory::Slot& FixedLagTrajectory::slot(Index t) { return ring_[static_cast<size_t>(t % (lag_ + 2))]; }

void FixedLagTrajectory::push_frame(const double* w, Index state, const double* target, std::vector<VectorXd>& out) {
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
  if (target != nullptr) {  // the evidence term: H[t,t] += W, r[t] += W ŷ_t
    dg_ += w_;
    rh_.noalias() += w_ * Eigen::Map<const VectorXd>(target, d);
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

void FixedLagTrajectory::check_targets(const MatrixRef& targets, Index rows) const {
  if (!evidence_) {
    fail_argument("targets were given, but this stream has no evidence: construct it with a precision "
                  "(FixedLagTrajectory(model, lag, precision)) or push without targets");
  }
  if (targets.rows() != rows || targets.cols() != model_.n_dims()) {
    fail_argument("targets must be ", rows, " x ", model_.n_dims(), " (one row per pushed frame), got ",
                  shape_of(targets), "; nothing was pushed");
  }
  require_finite(targets, "targets");
}

RowMatrixXd FixedLagTrajectory::push_states(const IndexVectorRef& states) {
  if (evidence_) {
    fail_argument("this stream has evidence: push_states needs the frames' targets (push_states(states, targets))");
  }
  return push_states_checked(states, nullptr);
}

RowMatrixXd FixedLagTrajectory::push_states(const IndexVectorRef& states, const MatrixRef& targets) {
  check_targets(targets, states.size());
  return push_states_checked(states, &targets);
}

RowMatrixXd FixedLagTrajectory::push_weights(const MatrixRef& weights) {
  if (evidence_) {
    fail_argument("this stream has evidence: push_weights needs the frames' targets (push_weights(weights, targets))");
  }
  return push_weights_checked(weights, nullptr);
}

RowMatrixXd FixedLagTrajectory::push_weights(const MatrixRef& weights, const MatrixRef& targets) {
  check_targets(targets, weights.rows());
  return push_weights_checked(weights, &targets);
}

RowMatrixXd FixedLagTrajectory::push_states_checked(const IndexVectorRef& states, const MatrixRef* targets) {
  for (Index t = 0; t < states.size(); ++t) {
    if (states[t] < 0 || states[t] >= model_.n_states()) {
      fail_argument("states[", t, "] = ", states[t], " is out of range: the model has ", model_.n_states(),
                    " states (valid indices 0 .. ", model_.n_states() - 1, "); nothing was pushed");
    }
  }
  std::vector<VectorXd> out;
  for (Index t = 0; t < states.size(); ++t) {
    push_frame(nullptr, states[t], targets ? targets->row(t).data() : nullptr, out);
  }
  return stack_rows(out, model_.n_dims());
}

RowMatrixXd FixedLagTrajectory::push_weights_checked(const MatrixRef& weights, const MatrixRef* targets) {
  if (weights.cols() != model_.n_states()) {
    fail_argument("weights must have ", model_.n_states(), " columns (one per state), got ", shape_of(weights));
  }
  for (Index t = 0; t < weights.rows(); ++t) check_weight_row(weights.row(t).data(), model_.n_states(), t, "weights");
  std::vector<VectorXd> out;
  for (Index t = 0; t < weights.rows(); ++t) {
    push_frame(weights.row(t).data(), 0, targets ? targets->row(t).data() : nullptr, out);
  }
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
