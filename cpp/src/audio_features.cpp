// The audio front end's per-frame work (audio_features.hpp).
#include "voicepuppet/audio_features.hpp"
#include "voicepuppet/interrupt.hpp"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>

#include <Eigen/Eigenvalues>
#include <unsupported/Eigen/FFT>

namespace voicepuppet {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kPi = 3.14159265358979323846;
constexpr double kInvalidCost = 1e6;  // local cost of an assignment with a missing formant

/// floor(a / b) for b > 0 and any sign of a.
Index floor_div(Index a, Index b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }
Index ceil_div(Index a, Index b) { return -floor_div(-a, b); }

/// Levinson-Durbin on raw pointers (the same operations, in the same order, as
/// voicepuppet.audio.lpc.levinson); a has order + 1 entries.
double levinson_raw(const double* r, Index order, double* a, double* tmp) {
  double err = r[0] * (1.0 + kLpcWhiteNoise) + kLpcEnergyFloor;
  a[0] = 1.0;
  for (Index i = 1; i <= order; ++i) a[i] = 0.0;
  for (Index i = 1; i <= order; ++i) {
    double acc = r[i];
    double dot = 0.0;
    for (Index j = 1; j < i; ++j) dot += a[j] * r[i - j];
    if (i > 1) acc += dot;
    const double k = -acc / err;
    if (i > 1) {
      for (Index j = 1; j < i; ++j) tmp[j] = a[j] + k * a[i - j];
      for (Index j = 1; j < i; ++j) a[j] = tmp[j];
    }
    a[i] = k;
    err = err * (1.0 - k * k);
  }
  return std::max(err, kLpcEnergyFloor * 1e-3);
}

void cepstrum_raw(const double* a, Index p, double err, Index n_ceps, double* c) {
  if (n_ceps <= 0) return;
  c[0] = std::log(err);
  for (Index n = 1; n < n_ceps; ++n) {
    double acc = n <= p ? -a[n] : 0.0;
    for (Index k = std::max<Index>(1, n - p); k < n; ++k)
      acc = acc - (static_cast<double>(k) / static_cast<double>(n)) * c[k] * a[n - k];
    c[n] = acc;
  }
}

void autocorrelation_raw(const double* x, Index n, Index max_lag, double* r) {
  for (Index l = 0; l <= max_lag; ++l) {
    double s = 0.0;
    for (Index j = 0; j + l < n; ++j) s += x[j] * x[j + l];
    r[l] = s;
  }
}

/// Value of the monic polynomial z^p + a_1 z^{p-1} + ... + a_p and its derivative (Horner).
void horner(const double* a, Index p, std::complex<double> z, std::complex<double>& f,
            std::complex<double>& df) {
  f = 1.0;
  df = 0.0;
  for (Index i = 1; i <= p; ++i) {
    df = df * z + f;
    f = f * z + a[i];
  }
}

void roots_raw(const double* a, Index p, std::vector<std::complex<double>>& out) {
  Eigen::MatrixXd comp = Eigen::MatrixXd::Zero(p, p);
  for (Index j = 0; j < p; ++j) comp(0, j) = -a[j + 1];
  for (Index i = 1; i < p; ++i) comp(i, i - 1) = 1.0;
  Eigen::EigenSolver<Eigen::MatrixXd> es(comp, false);
  if (es.info() != Eigen::Success)
    fail_numeric("lpc_roots: the companion-matrix eigenvalues did not converge");
  out.resize(static_cast<size_t>(p));
  for (Index i = 0; i < p; ++i) out[static_cast<size_t>(i)] = es.eigenvalues()[i];
  for (Index i = 0; i < p; ++i) {
    const std::complex<double> z0 = out[static_cast<size_t>(i)];
    std::complex<double> z = z0;
    // Newton steps on the polynomial refine the eigenvalue (a step is kept only when it lowers
    // |A(z)|), so the roots depend less on the eigenvalue solver's rounding.
    for (int it = 0; it < 2; ++it) {
      std::complex<double> f, df;
      horner(a, p, z, f, df);
      if (f == 0.0 || df == 0.0) break;
      const std::complex<double> zn = z - f / df;
      std::complex<double> fn, dfn;
      horner(a, p, zn, fn, dfn);
      if (!(std::abs(fn) < std::abs(f))) break;
      z = zn;
    }
    if (z0.imag() == 0.0) z.imag(0.0);  // real stays real
    out[static_cast<size_t>(i)] = z;
  }
}

void candidates_raw(const std::vector<std::complex<double>>& roots, double rate, double min_freq,
                    double max_bandwidth, double margin, Index n_max, double* freqs,
                    double* bands, std::vector<std::pair<double, double>>& work) {
  work.clear();
  for (const auto& r : roots) {
    const double f = std::arg(r) * (rate / (2.0 * kPi));
    const double mag = std::max(std::abs(r), 1e-300);
    const double bw = -std::log(mag) * (rate / kPi);
    if (r.imag() > 0 && f >= min_freq && f <= rate / 2.0 - margin && bw > 0 && bw <= max_bandwidth)
      work.emplace_back(f, bw);
  }
  std::sort(work.begin(), work.end(),
            [](const auto& x, const auto& y) { return x.first < y.first; });
  for (Index i = 0; i < n_max; ++i) {
    if (i < static_cast<Index>(work.size())) {
      freqs[i] = work[static_cast<size_t>(i)].first;
      bands[i] = work[static_cast<size_t>(i)].second;
    } else {
      freqs[i] = kNaN;
      bands[i] = kNaN;
    }
  }
}

/// A growing signal indexed globally from 0 (zeros before 0 and after the end), trimmed from
/// the left as the frames that need it are done.
struct Signal {
  std::vector<double> buf;
  Index offset = 0;  // global index of buf[0]
  Index n = 0;       // samples received

  void append(const double* x, Index k) {
    buf.insert(buf.end(), x, x + k);
    n += k;
  }
  /// Global samples start .. start + len - 1 into out (zeros outside 0 .. n - 1).
  void read(Index start, Index len, double* out) const {
    const Index a = std::clamp(start, Index(0), n), b = std::clamp(start + len, Index(0), n);
    std::fill(out, out + len, 0.0);
    if (b > a) std::copy(buf.data() + (a - offset), buf.data() + (b - offset), out + (a - start));
  }
  void trim(Index keep_from) {
    const Index cut = keep_from - offset;
    if (cut > 32768 && cut <= static_cast<Index>(buf.size())) {
      buf.erase(buf.begin(), buf.begin() + cut);
      offset = keep_from;
    }
  }
  void clear() {
    buf.clear();
    offset = 0;
    n = 0;
  }
};

/// Windows of one length centred on a frame grid: frame k holds
/// y[c_k - length / 2 ...] times the window, c_k = rint(k ratio), y pre-emphasised.
struct Framer {
  double ratio = 1.0;
  Index length = 0, half = 0;
  VectorXd window;
  double preemph = 0.0;
  Index next = 0;
  std::vector<double> raw;

  void init(double rate, double fps, const VectorXd& w, double pre) {
    ratio = rate / fps;
    window = w;
    length = w.size();
    half = length / 2;
    preemph = pre;
    next = 0;
    raw.assign(static_cast<size_t>(length + 1), 0.0);
  }
  Index centre(Index k) const { return static_cast<Index>(std::nearbyint(static_cast<double>(k) * ratio)); }
  /// Samples that must have arrived for frame k.
  Index needs(Index k) const { return centre(k) - half + length; }
  void frame(const Signal& s, Index k, double* out) {
    const Index start = centre(k) - half;
    if (preemph != 0.0) {
      s.read(start - 1, length + 1, raw.data());
      for (Index j = 0; j < length; ++j) out[j] = (raw[j + 1] - preemph * raw[j]) * window[j];
    } else {
      s.read(start, length, out);
      for (Index j = 0; j < length; ++j) out[j] *= window[j];
    }
  }
  Index first_needed() const { return centre(next) - half - 1; }
};

/// Rows of one output block, appended and taken from the front.
struct Queue {
  Index width = 0;
  std::vector<double> data;
  Index head = 0;  // rows already taken
  Index rows() const { return width ? static_cast<Index>(data.size()) / width - head : 0; }
  void push(const double* v) { data.insert(data.end(), v, v + width); }
  const double* row(Index i) const { return data.data() + (head + i) * width; }
  void pop(Index k) {
    head += k;
    if (head > 1024 && head * 2 > static_cast<Index>(data.size()) / std::max<Index>(width, 1)) {
      data.erase(data.begin(), data.begin() + head * width);
      head = 0;
    }
  }
};

/// A filterbank's rows with their nonzero span: products skip the exact zeros.
struct Filterbank {
  RowMatrixXd w;
  std::vector<Index> lo, hi;
  void init(const RowMatrixXd& m) {
    w = m;
    lo.assign(static_cast<size_t>(m.rows()), 0);
    hi.assign(static_cast<size_t>(m.rows()), 0);
    for (Index r = 0; r < m.rows(); ++r) {
      Index a = 0, b = m.cols();
      while (a < b && m(r, a) == 0.0) ++a;
      while (b > a && m(r, b - 1) == 0.0) --b;
      lo[static_cast<size_t>(r)] = a;
      hi[static_cast<size_t>(r)] = b;
    }
  }
  /// out[r] = w[r, :] . P
  void apply(const Eigen::VectorXd& P, double* out) const {
    for (Index r = 0; r < w.rows(); ++r) {
      const Index a = lo[static_cast<size_t>(r)], n = hi[static_cast<size_t>(r)] - a;
      out[r] = n > 0 ? w.row(r).segment(a, n).dot(P.segment(a, n).transpose()) : 0.0;
    }
  }
};

enum Block { kLpc, kLpcc, kRasta, kMfcc, kDmfcc, kFormants, kBands, kEnergy, kNBlocks };

const char* const kBlockNames[kNBlocks] = {"lpc", "lpc_cepstra", "rasta_plp", "mfcc",
                                           "mfcc_deltas", "formants", "bands", "log_energy"};

}  // namespace

// --------------------------------------------------------------------------- free functions
LpcFit levinson(const VectorRef& r, Index order) {
  if (order < 1) fail_argument("levinson: order must be >= 1, got ", order);
  if (r.size() < order + 1)
    fail_argument("levinson: r must have at least order + 1 = ", order + 1, " lags, got ", r.size());
  LpcFit fit;
  fit.a.resize(order + 1);
  std::vector<double> tmp(static_cast<size_t>(order + 1));
  fit.err = levinson_raw(r.data(), order, fit.a.data(), tmp.data());
  return fit;
}

VectorXd autocorrelation(const VectorRef& frame, Index max_lag) {
  if (max_lag < 0) fail_argument("autocorrelation: max_lag must be >= 0, got ", max_lag);
  VectorXd r(max_lag + 1);
  autocorrelation_raw(frame.data(), frame.size(), max_lag, r.data());
  return r;
}

VectorXd lpc_cepstrum(const VectorRef& a, double err, Index n_ceps) {
  if (a.size() < 1 || a[0] != 1.0) fail_argument("lpc_cepstrum: a must start with 1, got size ", a.size());
  if (!(err > 0)) fail_argument("lpc_cepstrum: err must be positive, got ", err);
  if (n_ceps < 1) fail_argument("lpc_cepstrum: n_ceps must be >= 1, got ", n_ceps);
  VectorXd c(n_ceps);
  cepstrum_raw(a.data(), a.size() - 1, err, n_ceps, c.data());
  return c;
}

std::vector<std::complex<double>> lpc_roots(const VectorRef& a) {
  if (a.size() < 2 || a[0] != 1.0)
    fail_argument("lpc_roots: a must be [1, a_1 .. a_p] with p >= 1, got size ", a.size());
  require_finite(a, "lpc_roots: a");
  std::vector<std::complex<double>> out;
  roots_raw(a.data(), a.size() - 1, out);
  return out;
}

void formant_candidates(const VectorRef& a, double rate, double min_freq, double max_bandwidth,
                        double margin, Index n_max, double* freqs, double* bands) {
  if (!(rate > 0)) fail_argument("formant_candidates: rate must be positive, got ", rate);
  std::vector<std::pair<double, double>> work;
  candidates_raw(lpc_roots(a), rate, min_freq, max_bandwidth, margin, n_max, freqs, bands, work);
}

// --------------------------------------------------------------------------- resampler
PolyphaseResampler::PolyphaseResampler(Index up, Index down, const VectorRef& taps)
    : up_(up), down_(down) {
  if (up < 1 || down < 1) fail_argument("resampler: up and down must be >= 1, got ", up, ", ", down);
  if (up == 1 && down == 1) {
    pre_remove_ = 0;
    return;
  }
  if (taps.size() < 1 || taps.size() % 2 == 0)
    fail_argument("resampler: taps must have an odd length 2 h + 1, got ", taps.size());
  require_finite(taps, "resampler: taps");
  const Index half_len = (taps.size() - 1) / 2;
  const Index n_pre_pad = down - half_len % down;
  h_ = VectorXd::Zero(n_pre_pad + taps.size());
  h_.tail(taps.size()) = taps;
  pre_remove_ = (half_len + n_pre_pad) / down;
  const Index L = h_.size();
  phases_.resize(static_cast<size_t>(up));
  for (Index ph = 0; ph < up; ++ph) {
    const Index K = ph < L ? (L - ph + up - 1) / up : 0;
    auto& rt = phases_[static_cast<size_t>(ph)];
    rt.resize(static_cast<size_t>(K));
    for (Index j = 0; j < K; ++j) rt[static_cast<size_t>(j)] = h_[ph + (K - 1 - j) * up];
  }
}

void PolyphaseResampler::reset() {
  buf_.clear();
  offset_ = n_ = done_ = 0;
}

double PolyphaseResampler::output(Index g) const {
  // y[g] = sum_i x[i] h[g down - i up]: inputs i0 - K + 1 .. i0 against the taps of phase
  // g down - i0 up, stored reversed so that both run forwards
  const Index gd = g * down_;
  const Index i0 = floor_div(gd, up_);
  const Index phase = gd - i0 * up_;
  const std::vector<double>& rt = phases_[static_cast<size_t>(phase)];
  const Index K = static_cast<Index>(rt.size());
  const Index first = i0 - K + 1;
  const Index lo = std::max<Index>(0, first), hi = std::min(i0, n_ - 1);
  double acc = 0.0;
  const double* x = buf_.data() - offset_;
  for (Index i = lo; i <= hi; ++i) acc += x[i] * rt[static_cast<size_t>(i - first)];
  return acc;
}

void PolyphaseResampler::trim() {
  const Index g0 = done_ + pre_remove_;
  const Index lo = std::max<Index>(0, ceil_div(g0 * down_ - h_.size() + 1, up_));
  const Index cut = lo - offset_;
  if (cut > 32768) {
    buf_.erase(buf_.begin(), buf_.begin() + cut);
    offset_ = lo;
  }
}

void PolyphaseResampler::push(const double* x, Index n, std::vector<double>& out) {
  if (up_ == 1 && down_ == 1) {
    out.insert(out.end(), x, x + n);
    n_ += n;
    return;
  }
  buf_.insert(buf_.end(), x, x + n);
  n_ += n;
  const Index ready_full = n_ ? (n_ * up_ - 1) / down_ + 1 : 0;
  const Index j1 = std::max(done_, ready_full - pre_remove_);
  for (Index j = done_; j < j1; ++j) out.push_back(output(j + pre_remove_));
  done_ = j1;
  trim();
}

void PolyphaseResampler::flush(std::vector<double>& out) {
  if (!(up_ == 1 && down_ == 1)) {
    const Index total = ceil_div(n_ * up_, down_);
    for (Index j = done_; j < total; ++j) out.push_back(output(j + pre_remove_));
  }
  reset();
}

// --------------------------------------------------------------------------- formant tracker
FormantTracker::FormantTracker(const VectorRef& reference, Index n_cand, Index max_delay)
    : ref_(reference), n_(reference.size()), max_delay_(max_delay) {
  if (n_ < 1 || n_ > 8) fail_argument("formant tracker: 1 to 8 reference formants, got ", n_);
  if (n_cand < n_) fail_argument("formant tracker: n_cand must be >= ", n_, ", got ", n_cand);
  if (!(reference.array() > 0).all()) fail_argument("formant tracker: reference frequencies must be positive");
  if (max_delay < -1) fail_argument("formant tracker: max_delay must be -1 (exact) or >= 0, got ", max_delay);
  // increasing choices of n_ of the n_cand candidates, in lexicographic order
  std::vector<Index> c(static_cast<size_t>(n_));
  for (Index i = 0; i < n_; ++i) c[static_cast<size_t>(i)] = i;
  while (true) {
    combos_.insert(combos_.end(), c.begin(), c.end());
    Index i = n_ - 1;
    while (i >= 0 && c[static_cast<size_t>(i)] == n_cand - n_ + i) --i;
    if (i < 0) break;
    ++c[static_cast<size_t>(i)];
    for (Index j = i + 1; j < n_; ++j) c[static_cast<size_t>(j)] = c[static_cast<size_t>(j - 1)] + 1;
  }
  S_ = static_cast<Index>(combos_.size()) / n_;
  reset();
}

void FormantTracker::reset() {
  score_.assign(static_cast<size_t>(S_), 0.0);
  prev_logF_.assign(static_cast<size_t>(S_ * n_), 0.0);
  logF_.assign(static_cast<size_t>(S_ * n_), 0.0);
  local_.assign(static_cast<size_t>(S_), 0.0);
  prev_valid_.assign(static_cast<size_t>(S_), 0);
  started_ = false;
  t_ = base_ = out_next_ = forced_ = 0;
  pending_.clear();
  decided_.clear();
  decided_head_ = 0;
  has_last_ = any_good_ = false;
  last_frame_ = 0;
}

void FormantTracker::put(const double* v, std::vector<double>& out) const {
  out.insert(out.end(), v, v + n_);
}

void FormantTracker::push(const double* freqs, const double* bands, std::vector<double>& out) {
  Pending p;
  p.F.resize(static_cast<size_t>(S_ * n_));
  p.valid.resize(static_cast<size_t>(S_));
  p.back.assign(static_cast<size_t>(S_), 0);
  for (Index s = 0; s < S_; ++s) {
    bool ok = true;
    double c1 = 0.0, c2 = 0.0;
    for (Index i = 0; i < n_; ++i) {
      const Index k = combos_[static_cast<size_t>(s * n_ + i)];
      const double F = freqs[k];
      p.F[static_cast<size_t>(s * n_ + i)] = F;
      if (!std::isfinite(F)) {
        ok = false;
        logF_[static_cast<size_t>(s * n_ + i)] = 0.0;
        continue;
      }
      logF_[static_cast<size_t>(s * n_ + i)] = std::log(F);
      c1 += std::abs(F - ref_[i]) / ref_[i];
      c2 += bands[k] / F;
    }
    p.valid[static_cast<size_t>(s)] = ok;
    local_[static_cast<size_t>(s)] = ok ? c1 + c2 : kInvalidCost;
  }
  if (!started_) {
    for (Index s = 0; s < S_; ++s) score_[static_cast<size_t>(s)] = local_[static_cast<size_t>(s)];
    started_ = true;
  } else {
    std::vector<double> next(static_cast<size_t>(S_));
    for (Index s = 0; s < S_; ++s) {
      Index best = 0;
      double best_v = 0.0;
      for (Index sp = 0; sp < S_; ++sp) {  // the first minimum, as numpy's argmin
        double tr = 0.0;
        if (prev_valid_[static_cast<size_t>(sp)] && p.valid[static_cast<size_t>(s)]) {
          for (Index i = 0; i < n_; ++i)
            tr += std::abs(logF_[static_cast<size_t>(s * n_ + i)] - prev_logF_[static_cast<size_t>(sp * n_ + i)]);
        }
        const double tot = score_[static_cast<size_t>(sp)] + tr;
        if (sp == 0 || tot < best_v) {
          best_v = tot;
          best = sp;
        }
      }
      p.back[static_cast<size_t>(s)] = best;
      next[static_cast<size_t>(s)] = best_v + local_[static_cast<size_t>(s)];
    }
    score_.swap(next);
  }
  std::swap(prev_logF_, logF_);
  for (Index s = 0; s < S_; ++s) prev_valid_[static_cast<size_t>(s)] = p.valid[static_cast<size_t>(s)];
  pending_.push_back(std::move(p));
  ++t_;
  decide_converged();
  emit(false, out);
}

std::vector<Index> FormantTracker::trace_one(Index end_state) const {
  const Index P = static_cast<Index>(pending_.size());
  std::vector<Index> path(static_cast<size_t>(P));
  Index cur = end_state;
  path[static_cast<size_t>(P - 1)] = cur;
  for (Index i = P - 1; i > 0; --i) {
    cur = pending_[static_cast<size_t>(i)].back[static_cast<size_t>(cur)];
    path[static_cast<size_t>(i - 1)] = cur;
  }
  return path;
}

void FormantTracker::commit(const std::vector<Index>& states, Index k) {
  for (Index i = 0; i < k; ++i) {
    const Pending& p = pending_[static_cast<size_t>(i)];
    const Index s = states[static_cast<size_t>(i)];
    Decided d;
    d.frame = base_ + i;
    d.good = p.valid[static_cast<size_t>(s)] != 0;
    for (Index j = 0; j < n_; ++j) d.v[static_cast<size_t>(j)] = p.F[static_cast<size_t>(s * n_ + j)];
    decided_.push_back(d);
  }
  pending_.erase(pending_.begin(), pending_.begin() + k);
  base_ += k;
}

void FormantTracker::decide_converged() {
  const Index P = static_cast<Index>(pending_.size());
  if (P <= 1) return;
  // trace every end state back together; the last frame where all agree is final, with every
  // frame before it (agreement propagates backwards)
  std::vector<Index> cur(static_cast<size_t>(S_));
  for (Index s = 0; s < S_; ++s) cur[static_cast<size_t>(s)] = s;
  Index u = -1;
  for (Index i = P - 1; i >= 0; --i) {
    if (i < P - 1) {
      const auto& back = pending_[static_cast<size_t>(i + 1)].back;
      for (auto& c : cur) c = back[static_cast<size_t>(c)];
    }
    bool same = true;
    for (Index s = 1; s < S_ && same; ++s) same = cur[static_cast<size_t>(s)] == cur[0];
    if (same) {
      u = i;
      break;
    }
  }
  if (u < 0 || u >= P - 1) return;  // the last pending frame stays (its back pointers are needed)
  std::vector<Index> states(static_cast<size_t>(u + 1));
  Index c = cur[0];
  states[static_cast<size_t>(u)] = c;
  for (Index i = u; i > 0; --i) {
    c = pending_[static_cast<size_t>(i)].back[static_cast<size_t>(c)];
    states[static_cast<size_t>(i - 1)] = c;
  }
  commit(states, u + 1);
}

void FormantTracker::fill_gap_to(Index frame, const double* val, std::vector<double>& out) {
  while (decided_head_ < decided_.size() && decided_[decided_head_].frame < frame) {
    const Index g = decided_[decided_head_].frame;
    ++decided_head_;
    if (!has_last_) {
      put(val, out);  // leading gap: holds the first value
    } else {
      std::array<double, 8> v{};
      const double x0 = static_cast<double>(last_frame_), x1 = static_cast<double>(frame);
      for (Index i = 0; i < n_; ++i) {
        const double f0 = last_val_[static_cast<size_t>(i)];
        const double slope = (val[i] - f0) / (x1 - x0);
        v[static_cast<size_t>(i)] = slope * (static_cast<double>(g) - x0) + f0;
      }
      put(v.data(), out);
    }
    ++out_next_;
  }
}

void FormantTracker::emit(bool final, std::vector<double>& out) {
  while (decided_head_ < decided_.size()) {
    const Decided d = decided_[decided_head_];
    if (d.frame != out_next_) fail_numeric("formant tracker: frames out of order (a bug)");
    if (d.good) {
      fill_gap_to(d.frame, d.v.data(), out);
      put(d.v.data(), out);
      last_frame_ = d.frame;
      last_val_ = d.v;
      has_last_ = any_good_ = true;
      ++decided_head_;
      ++out_next_;
      continue;
    }
    // a gap frame: needs the next good frame (or the end of the stream)
    size_t j = decided_head_ + 1;
    while (j < decided_.size() && !decided_[j].good) ++j;
    if (j < decided_.size()) {
      const Decided nxt = decided_[j];
      fill_gap_to(nxt.frame, nxt.v.data(), out);
      continue;
    }
    if (final) {
      ++decided_head_;
      put(has_last_ ? last_val_.data() : ref_.data(), out);  // no good frame at all: the reference
      ++out_next_;
      continue;
    }
    if (max_delay_ >= 0 && t_ - 1 - d.frame >= max_delay_) {
      ++decided_head_;
      put(has_last_ ? last_val_.data() : ref_.data(), out);
      ++forced_;
      ++out_next_;
      continue;
    }
    break;
  }
  if (decided_head_ > 256 && decided_head_ * 2 > decided_.size()) {
    decided_.erase(decided_.begin(), decided_.begin() + static_cast<std::ptrdiff_t>(decided_head_));
    decided_head_ = 0;
  }
}

void FormantTracker::force(std::vector<double>& out) {
  if (max_delay_ < 0 || pending_.empty()) return;
  if (t_ - 1 - base_ < max_delay_) return;
  const Index best = static_cast<Index>(std::min_element(score_.begin(), score_.end()) - score_.begin());
  const std::vector<Index> path = trace_one(best);
  const Index k = std::min(static_cast<Index>(path.size()), (t_ - 1 - max_delay_) - base_ + 1);
  if (k <= 0) return;
  forced_ += k;
  commit(path, k);
  emit(false, out);
}

void FormantTracker::finish(std::vector<double>& out) {
  if (!pending_.empty()) {
    const Index best = static_cast<Index>(std::min_element(score_.begin(), score_.end()) - score_.begin());
    const std::vector<Index> path = trace_one(best);
    commit(path, static_cast<Index>(path.size()));
  }
  emit(true, out);
}

// --------------------------------------------------------------------------- the stream
struct StreamingAudioFeatures::Impl {
  AudioFeatureOptions o;
  bool want[kNBlocks] = {};
  Index width[kNBlocks] = {};
  bool spec = false, lpc = false, fmt = false;
  Index n_bins = 0, n_bark = 0, n_mels = 0, n_mfcc = 0;

  Signal sig, fsig;
  Framer spec_fr, lpc_fr, fmt_fr;
  std::unique_ptr<PolyphaseResampler> resampler;
  std::unique_ptr<FormantTracker> tracker;
  Eigen::FFT<double> fft;
  Queue q[kNBlocks];
  Index frames_out = 0;
  Index limit = -1;  // frames never computed beyond (process); -1: none

  // spectral state
  bool rasta_started = false;
  std::vector<double> rasta_z;   // 4 per Bark band
  std::vector<std::vector<double>> mfcc_hist;
  Index mfcc_base = 0, mfcc_done = 0;
  RowMatrixXd plp_cos;           // (rasta_order + 1) x N
  Filterbank mel_fb, band_fb, bark_fb;
  Eigen::VectorXd mel, bandE;
  // scratch
  std::vector<double> frame, ac, a, tmp, cep, fbuf, ffreq, fband, plp_z;
  std::vector<std::complex<double>> spectrum, roots;
  std::vector<std::pair<double, double>> cand_work;
  Eigen::VectorXd P, logb, filt;

  explicit Impl(AudioFeatureOptions opt) : o(std::move(opt)) {
    if (!(o.rate >= 1.0) || o.rate != std::floor(o.rate))
      fail_argument("audio features: rate must be a whole number of Hz, got ", o.rate);
    if (!(o.fps > 0) || !std::isfinite(o.fps))
      fail_argument("audio features: fps must be positive and finite, got ", o.fps);
    if (o.features.empty()) fail_argument("audio features: features must name at least one block");
    for (const auto& f : o.features) {
      int b = -1;
      for (int i = 0; i < kNBlocks; ++i)
        if (f == kBlockNames[i]) b = i;
      if (b < 0)
        fail_argument("audio features: unknown feature '", f, "'; streamable features are lpc, "
                      "lpc_cepstra, rasta_plp, mfcc, mfcc_deltas, formants, bands, log_energy");
      if (want[b]) fail_argument("audio features: feature '", f, "' listed twice");
      want[b] = true;
    }
    spec = want[kMfcc] || want[kDmfcc] || want[kRasta] || want[kBands] || want[kEnergy];
    lpc = want[kLpc] || want[kLpcc];
    fmt = want[kFormants];
    if (spec) {
      if (o.n_fft < 2 || o.spectral_window.size() != o.n_fft)
        fail_argument("audio features: spectral_window must have n_fft = ", o.n_fft,
                      " entries (n_fft >= 2), got ", o.spectral_window.size());
      n_bins = o.n_fft / 2 + 1;
      if (o.fine < 1) fail_argument("audio features: fine must be >= 1, got ", o.fine);
      spec_fr.init(o.rate, o.fps * static_cast<double>(o.fine), o.spectral_window, 0.0);
      frame.resize(static_cast<size_t>(o.n_fft));
      fft.SetFlag(Eigen::FFT<double>::HalfSpectrum);
      if (want[kMfcc] || want[kDmfcc]) {
        if (o.mel_filters.cols() != n_bins || o.mel_filters.rows() < 1)
          fail_argument("audio features: mel_filters must be (n_mels, ", n_bins, "), got ",
                        shape_of(o.mel_filters));
        n_mels = o.mel_filters.rows();
        if (o.dct.cols() != n_mels || o.dct.rows() < 1)
          fail_argument("audio features: dct must be (n_mfcc, ", n_mels, "), got ", shape_of(o.dct));
        n_mfcc = o.dct.rows();
        mel_fb.init(o.mel_filters);
        mel.resize(n_mels);
        if (want[kDmfcc] && o.delta_width < 1)
          fail_argument("audio features: delta_width must be >= 1, got ", o.delta_width);
      }
      if (want[kBands] && (o.band_weights.cols() != n_bins || o.band_weights.rows() < 1))
        fail_argument("audio features: band_weights must be (n_bands, ", n_bins, "), got ",
                      shape_of(o.band_weights));
      if (want[kBands]) {
        band_fb.init(o.band_weights);
        bandE.resize(o.band_weights.rows());
      }
      if ((want[kEnergy]) && o.parseval.size() != n_bins)
        fail_argument("audio features: parseval must have ", n_bins, " entries, got ", o.parseval.size());
      if (want[kRasta]) {
        if (o.bark_filters.cols() != n_bins || o.bark_filters.rows() < 3)
          fail_argument("audio features: bark_filters must be (n_bark >= 3, ", n_bins, "), got ",
                        shape_of(o.bark_filters));
        n_bark = o.bark_filters.rows();
        bark_fb.init(o.bark_filters);
        if (o.loudness.size() != n_bark)
          fail_argument("audio features: loudness must have ", n_bark, " entries, got ", o.loudness.size());
        if (o.rasta_b.size() != 5 || o.rasta_zi.size() != 4)
          fail_argument("audio features: rasta_b must have 5 and rasta_zi 4 entries, got ",
                        o.rasta_b.size(), " and ", o.rasta_zi.size());
        if (o.rasta_order < 1 || o.n_rasta < 1 || o.rasta_first < 0 || o.rasta_first >= o.n_rasta)
          fail_argument("audio features: need rasta_order >= 1 and 0 <= rasta_first < n_rasta, got ",
                        o.rasta_order, ", ", o.rasta_first, ", ", o.n_rasta);
        const Index N = 2 * n_bark - 2;
        plp_cos.resize(o.rasta_order + 1, N);
        for (Index k = 0; k <= o.rasta_order; ++k)
          for (Index n = 0; n < N; ++n)
            plp_cos(k, n) = std::cos(2.0 * kPi * static_cast<double>((n * k) % N) / static_cast<double>(N));
        rasta_z.assign(static_cast<size_t>(4 * n_bark), 0.0);
      }
    }
    if (lpc) {
      if (o.lpc_order < 1 || o.lpc_window.size() < o.lpc_order + 1)
        fail_argument("audio features: lpc_window must have more than lpc_order = ", o.lpc_order,
                      " entries (order >= 1), got ", o.lpc_window.size());
      if (want[kLpcc] && o.n_lpc_cepstra < 1)
        fail_argument("audio features: n_lpc_cepstra must be >= 1, got ", o.n_lpc_cepstra);
      lpc_fr.init(o.rate, o.fps, o.lpc_window, o.lpc_preemph);
    }
    if (fmt) {
      if (!(o.formant_rate >= 1.0))
        fail_argument("audio features: formant_rate must be positive, got ", o.formant_rate);
      if (o.formant_order < 2 || o.formant_window.size() < o.formant_order + 1)
        fail_argument("audio features: formant_window must have more than formant_order = ",
                      o.formant_order, " entries, got ", o.formant_window.size());
      if (o.formant_reference.size() < 1)
        fail_argument("audio features: formant_reference must list the reference formants");
      if (o.formant_lag < -1)
        fail_argument("audio features: formant_lag must be -1 (exact) or >= 0 frames, got ", o.formant_lag);
      resampler = std::make_unique<PolyphaseResampler>(o.resample_up, o.resample_down, o.resample_taps);
      fmt_fr.init(o.formant_rate, o.fps, o.formant_window, o.formant_preemph);
      tracker = std::make_unique<FormantTracker>(o.formant_reference, (o.formant_order + 1) / 2,
                                                 o.formant_lag);
    }
    width[kLpc] = o.lpc_order;
    width[kLpcc] = o.n_lpc_cepstra;
    width[kRasta] = o.n_rasta - o.rasta_first;
    width[kMfcc] = n_mfcc;
    width[kDmfcc] = n_mfcc;
    width[kFormants] = o.formant_reference.size();
    width[kBands] = o.band_weights.rows();
    width[kEnergy] = 1;
    for (int b = 0; b < kNBlocks; ++b) q[b].width = want[b] ? width[b] : 0;
    const Index order_max = std::max({o.lpc_order, o.formant_order, o.rasta_order}) + 1;
    ac.resize(static_cast<size_t>(order_max + 1));
    a.resize(static_cast<size_t>(order_max + 1));
    tmp.resize(static_cast<size_t>(order_max + 1));
    cep.resize(static_cast<size_t>(std::max({o.n_lpc_cepstra, o.n_rasta, Index(1)}) + 1));
    fbuf.resize(static_cast<size_t>(std::max(o.lpc_window.size(), o.formant_window.size())));
    const Index nc = (o.formant_order + 1) / 2;
    ffreq.resize(static_cast<size_t>(nc));
    fband.resize(static_cast<size_t>(nc));
    plp_z.resize(static_cast<size_t>(2 * std::max<Index>(n_bark, 1)));
  }

  Index n_features() const {
    Index d = 0;
    for (int b = 0; b < kNBlocks; ++b)
      if (want[b]) d += width[b];
    return d;
  }

  void reset() {
    sig.clear();
    fsig.clear();
    if (spec) spec_fr.next = 0;
    if (lpc) lpc_fr.next = 0;
    if (fmt) {
      fmt_fr.next = 0;
      resampler->reset();
      tracker->reset();
    }
    for (auto& qq : q) {
      qq.data.clear();
      qq.head = 0;
    }
    frames_out = 0;
    limit = -1;
    rasta_started = false;
    std::fill(rasta_z.begin(), rasta_z.end(), 0.0);
    mfcc_hist.clear();
    mfcc_base = mfcc_done = 0;
  }

  // one fine spectral frame k
  void spectral_frame(Index k) {
    spec_fr.frame(sig, k, frame.data());
    fft.fwd(spectrum, frame);
    P.resize(n_bins);
    for (Index j = 0; j < n_bins; ++j) P[j] = std::norm(spectrum[static_cast<size_t>(j)]);
    const bool video = (k % o.fine) == 0;
    if (want[kRasta]) {
      logb.resize(n_bark);
      bark_fb.apply(P, logb.data());
      for (Index b = 0; b < n_bark; ++b) logb[b] = std::log(logb[b] + kPowerFloor);
      if (!rasta_started) {
        for (Index b = 0; b < n_bark; ++b)
          for (int i = 0; i < 4; ++i) rasta_z[static_cast<size_t>(4 * b + i)] = o.rasta_zi[i] * logb[b];
        rasta_started = true;
      }
      filt.resize(n_bark);
      const double a1 = -o.rasta_pole;
      const double* bb = o.rasta_b.data();
      for (Index b = 0; b < n_bark; ++b) {
        double* z = &rasta_z[static_cast<size_t>(4 * b)];
        const double x = logb[b];
        const double y = z[0] + bb[0] * x;
        z[0] = z[1] + x * bb[1] - y * a1;
        z[1] = z[2] + x * bb[2];
        z[2] = z[3] + x * bb[3];
        z[3] = x * bb[4];
        filt[b] = y;
      }
      if (video) plp_row();
    }
    if (!video) return;
    if (want[kMfcc] || want[kDmfcc]) {
      mel_fb.apply(P, mel.data());
      for (Index i = 0; i < n_mels; ++i) mel[i] = 10.0 * std::log10(std::max(mel[i], kPowerFloor));
      Eigen::VectorXd mf = o.dct * mel;
      if (want[kMfcc]) q[kMfcc].push(mf.data());
      if (want[kDmfcc]) mfcc_hist.emplace_back(mf.data(), mf.data() + n_mfcc);
    }
    if (want[kBands]) {
      band_fb.apply(P, bandE.data());
      for (Index i = 0; i < bandE.size(); ++i) bandE[i] = 10.0 * std::log10(bandE[i] + kPowerFloor);
      q[kBands].push(bandE.data());
    }
    if (want[kEnergy]) {
      const double e = 10.0 * std::log10(o.parseval.dot(P) + kPowerFloor);
      q[kEnergy].push(&e);
    }
  }

  void plp_row() {
    const Index nb = n_bark, N = 2 * nb - 2;
    for (Index b = 0; b < nb; ++b) plp_z[static_cast<size_t>(b)] = std::cbrt(std::max(std::exp(filt[b]) * o.loudness[b], 0.0));
    plp_z[0] = plp_z[1];
    plp_z[static_cast<size_t>(nb - 1)] = plp_z[static_cast<size_t>(nb - 2)];
    for (Index i = 0; i < nb - 2; ++i) plp_z[static_cast<size_t>(nb + i)] = plp_z[static_cast<size_t>(nb - 2 - i)];
    const Index p = o.rasta_order;
    for (Index k = 0; k <= p; ++k) {
      double s = 0.0;
      for (Index n = 0; n < N; ++n) s += plp_z[static_cast<size_t>(n)] * plp_cos(k, n);
      ac[static_cast<size_t>(k)] = s / static_cast<double>(N);
    }
    const double err = levinson_raw(ac.data(), p, a.data(), tmp.data());
    cepstrum_raw(a.data(), p, err, o.n_rasta, cep.data());
    q[kRasta].push(cep.data() + o.rasta_first);
  }

  void lpc_frame(Index k) {
    const Index L = lpc_fr.length, p = o.lpc_order;
    lpc_fr.frame(sig, k, fbuf.data());
    autocorrelation_raw(fbuf.data(), L, p, ac.data());
    const double err = levinson_raw(ac.data(), p, a.data(), tmp.data());
    if (want[kLpc]) q[kLpc].push(a.data() + 1);
    if (want[kLpcc]) {
      cepstrum_raw(a.data(), p, err, o.n_lpc_cepstra + 1, cep.data());
      q[kLpcc].push(cep.data() + 1);
    }
  }

  std::vector<double> fmt_out, resampled;

  void formant_frame(Index k) {
    const Index L = fmt_fr.length, p = o.formant_order;
    fmt_fr.frame(fsig, k, fbuf.data());
    autocorrelation_raw(fbuf.data(), L, p, ac.data());
    levinson_raw(ac.data(), p, a.data(), tmp.data());
    roots_raw(a.data(), p, roots);
    candidates_raw(roots, o.formant_rate, o.formant_min_freq, o.formant_max_bandwidth,
                   o.formant_margin, static_cast<Index>(ffreq.size()), ffreq.data(), fband.data(),
                   cand_work);
    tracker->push(ffreq.data(), fband.data(), fmt_out);
  }

  void take_formants() {
    const Index w = width[kFormants];
    for (size_t i = 0; i < fmt_out.size(); i += static_cast<size_t>(w)) q[kFormants].push(&fmt_out[i]);
    fmt_out.clear();
  }

  /// Deltas of the mfcc rows whose neighbours are known; total >= 0: the stream's end.
  void deltas(Index total) {
    const Index w = o.delta_width;
    const Index n_have = mfcc_base + static_cast<Index>(mfcc_hist.size());
    const Index start = mfcc_done;
    const Index end = total >= 0 ? n_have : n_have - w;
    if (end <= start || n_have == 0) return;
    double denom = 0.0;
    for (Index n = 1; n <= w; ++n) denom += static_cast<double>(n * n);
    denom *= 2.0;
    std::vector<double> num(static_cast<size_t>(n_mfcc));
    for (Index t = start; t < end; ++t) {
      std::fill(num.begin(), num.end(), 0.0);
      for (Index n = 1; n <= w; ++n) {
        const Index hi = total >= 0 ? std::min(t + n, total - 1) : t + n;
        const Index lo = std::max<Index>(t - n, 0);
        const auto& xh = mfcc_hist[static_cast<size_t>(hi - mfcc_base)];
        const auto& xl = mfcc_hist[static_cast<size_t>(lo - mfcc_base)];
        for (Index j = 0; j < n_mfcc; ++j)
          num[static_cast<size_t>(j)] += static_cast<double>(n) * (xh[static_cast<size_t>(j)] - xl[static_cast<size_t>(j)]);
      }
      for (auto& v : num) v /= denom;
      q[kDmfcc].push(num.data());
    }
    mfcc_done = end;
    const Index keep_from = std::max(mfcc_base, end - w);
    mfcc_hist.erase(mfcc_hist.begin(), mfcc_hist.begin() + (keep_from - mfcc_base));
    mfcc_base = keep_from;
  }

  /// Compute every frame whose windows are complete; total >= 0: the stream has ended and
  /// frames up to total are computed (windows past the end see zeros).
  void advance(Index total) {
    const Index cap = total >= 0 ? total : limit;
    if (spec) {
      const Index kmax = cap >= 0 ? cap * o.fine : std::numeric_limits<Index>::max();
      while (spec_fr.next < kmax && (total >= 0 || spec_fr.needs(spec_fr.next) <= sig.n))
        spectral_frame(spec_fr.next++);
      if (want[kDmfcc]) deltas(total);
    }
    if (lpc) {
      const Index kmax = cap >= 0 ? cap : std::numeric_limits<Index>::max();
      while (lpc_fr.next < kmax && (total >= 0 || lpc_fr.needs(lpc_fr.next) <= sig.n))
        lpc_frame(lpc_fr.next++);
    }
    if (fmt) {
      const Index kmax = cap >= 0 ? cap : std::numeric_limits<Index>::max();
      while (fmt_fr.next < kmax && (total >= 0 || fmt_fr.needs(fmt_fr.next) <= fsig.n))
        formant_frame(fmt_fr.next++);
    }
    // forget samples no frame needs any more
    Index keep = std::numeric_limits<Index>::max();
    if (spec) keep = std::min(keep, spec_fr.first_needed());
    if (lpc) keep = std::min(keep, lpc_fr.first_needed());
    if (spec || lpc) sig.trim(keep);
    if (fmt) fsig.trim(fmt_fr.first_needed());
  }

  void feed(const double* x, Index n) {
    constexpr Index kBlock = 16384;  // bounds the buffers when a whole recording is pushed
    for (Index i0 = 0; i0 < n; i0 += kBlock) {
      check_interrupt();
      const Index k = std::min(kBlock, n - i0);
      if (spec || lpc) sig.append(x + i0, k);
      else sig.n += k;
      if (fmt) {
        resampled.clear();
        resampler->push(x + i0, k, resampled);
        fsig.append(resampled.data(), static_cast<Index>(resampled.size()));
      }
      advance(-1);
    }
  }

  RowMatrixXd assemble(Index expect) {
    Index n = std::numeric_limits<Index>::max();
    for (int b = 0; b < kNBlocks; ++b)
      if (want[b]) n = std::min(n, q[b].rows());
    if (expect >= 0 && n != expect)
      fail_numeric("audio features: ", n, " finished rows for ", expect, " frames (a bug)");
    RowMatrixXd out(n, n_features());
    Index col = 0;
    for (const auto& f : o.features) {
      int b = 0;
      while (f != kBlockNames[b]) ++b;
      for (Index i = 0; i < n; ++i)
        std::copy(q[b].row(i), q[b].row(i) + width[b], out.row(i).data() + col);
      q[b].pop(n);
      col += width[b];
    }
    frames_out += n;
    return out;
  }

  RowMatrixXd push(const double* x, Index n) {
    for (Index i = 0; i < n; ++i)
      if (!std::isfinite(x[i]))
        fail_argument("audio features: samples contain NaN or infinite values (first at index ", i,
                      "); the source is corrupt");
    feed(x, n);
    if (fmt) {
      tracker->force(fmt_out);
      take_formants();
    }
    return assemble(-1);
  }

  Index default_total() const {
    if (sig.n == 0) return 0;
    return std::max<Index>(1, static_cast<Index>(std::ceil(static_cast<double>(sig.n) * o.fps / o.rate - 1e-9)));
  }

  RowMatrixXd flush(Index total) {
    if (total < 0) total = default_total();
    Index computed = frames_out;
    if (spec) computed = std::max(computed, ceil_div(spec_fr.next, o.fine));
    if (lpc) computed = std::max(computed, lpc_fr.next);
    if (fmt) computed = std::max(computed, fmt_fr.next);
    if (total < computed)
      fail_argument("audio features: flush(total=", total, ") is below the ", computed,
                    " frames already computed; to cap a recording at a frame count use "
                    "process(samples, total)");
    if (total == 0) {
      reset();
      return RowMatrixXd(0, n_features());
    }
    if (fmt) {
      resampled.clear();
      resampler->flush(resampled);
      fsig.append(resampled.data(), static_cast<Index>(resampled.size()));
    }
    advance(total);
    if (fmt) {
      tracker->force(fmt_out);
      tracker->finish(fmt_out);
      take_formants();
    }
    RowMatrixXd out = assemble(total - frames_out);
    reset();
    return out;
  }
};

StreamingAudioFeatures::StreamingAudioFeatures(AudioFeatureOptions options)
    : impl_(std::make_unique<Impl>(std::move(options))) {}
StreamingAudioFeatures::~StreamingAudioFeatures() = default;
StreamingAudioFeatures::StreamingAudioFeatures(StreamingAudioFeatures&&) noexcept = default;
StreamingAudioFeatures& StreamingAudioFeatures::operator=(StreamingAudioFeatures&&) noexcept = default;

RowMatrixXd StreamingAudioFeatures::push(const VectorRef& samples) {
  return impl_->push(samples.data(), samples.size());
}

RowMatrixXd StreamingAudioFeatures::flush(Index total) { return impl_->flush(total); }

RowMatrixXd StreamingAudioFeatures::process(const VectorRef& samples, Index total) {
  impl_->reset();
  const Index n = samples.size();
  const Index T = total >= 0 ? total
                             : (n == 0 ? 0
                                       : std::max<Index>(1, static_cast<Index>(std::ceil(
                                             static_cast<double>(n) * impl_->o.fps / impl_->o.rate - 1e-9))));
  impl_->limit = T;
  RowMatrixXd head;
  try {
    head = impl_->push(samples.data(), n);
  } catch (...) {
    impl_->reset();
    throw;
  }
  RowMatrixXd tail = impl_->flush(T);
  RowMatrixXd out(head.rows() + tail.rows(), impl_->n_features());
  out.topRows(head.rows()) = head;
  out.bottomRows(tail.rows()) = tail;
  return out;
}

void StreamingAudioFeatures::reset() { impl_->reset(); }
Index StreamingAudioFeatures::n_features() const { return impl_->n_features(); }
Index StreamingAudioFeatures::frames_out() const { return impl_->frames_out; }
Index StreamingAudioFeatures::samples_in() const { return impl_->sig.n; }
Index StreamingAudioFeatures::formants_forced() const { return impl_->fmt ? impl_->tracker->forced() : 0; }
const AudioFeatureOptions& StreamingAudioFeatures::options() const { return impl_->o; }

}  // namespace voicepuppet
