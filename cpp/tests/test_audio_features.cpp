// The audio front end's pieces against closed forms: a sinusoid's band energy and log energy,
// an AR process's LPC, the cepstrum of a one-pole model, a known resonance's formant, the
// polyphase resampler against the dense definition, the formant tracker on planted candidates,
// and the stream's independence of the chunking.
#include <doctest/doctest.h>

#include <cmath>
#include <limits>
#include <random>

#include <Eigen/Cholesky>

#include "voicepuppet/audio_features.hpp"

using namespace voicepuppet;

namespace {

constexpr double kPi = 3.14159265358979323846;
const double kNaN = std::numeric_limits<double>::quiet_NaN();

/// Periodic Hann window of `n`, centred in `n_fft` (the front end's analysis window).
VectorXd hann_in(Index n, Index n_fft) {
  VectorXd w = VectorXd::Zero(n_fft);
  const Index left = (n_fft - n) / 2;
  for (Index i = 0; i < n; ++i) w[left + i] = 0.5 - 0.5 * std::cos(2.0 * kPi * i / n);
  return w;
}

/// Spectral options for bands + log energy at 16 kHz, 400-point FFT, with Parseval weights
/// (one-sided power -> mean square of the windowed frame over the window energy).
AudioFeatureOptions band_options() {
  AudioFeatureOptions o;
  o.rate = 16000.0;
  o.fps = 100.0;
  o.features = {"bands", "log_energy"};
  o.n_fft = 400;
  o.spectral_window = hann_in(400, 400);
  const Index nb = o.n_fft / 2 + 1;
  const double wE = o.spectral_window.squaredNorm();
  o.parseval = VectorXd::Constant(nb, 2.0);
  o.parseval[0] = o.parseval[nb - 1] = 1.0;
  o.parseval /= o.n_fft * wE;
  const double edges[5] = {80.0, 400.0, 1000.0, 2500.0, 4000.0};
  o.band_weights = RowMatrixXd::Zero(4, nb);
  for (Index b = 0; b < 4; ++b)
    for (Index k = 0; k < nb; ++k) {
      const double f = k * o.rate / o.n_fft;
      if (f >= edges[b] && f < edges[b + 1]) o.band_weights(b, k) = o.parseval[k];
    }
  return o;
}

VectorXd sinusoid(Index n, double amp, double freq, double rate) {
  VectorXd x(n);
  for (Index i = 0; i < n; ++i) x[i] = amp * std::sin(2.0 * kPi * freq * i / rate + 0.3);
  return x;
}

RowMatrixXd push_in_chunks(StreamingAudioFeatures& s, const VectorXd& x, Index chunk) {
  RowMatrixXd all(0, s.n_features());
  auto add = [&all](const RowMatrixXd& r) {
    RowMatrixXd t(all.rows() + r.rows(), all.cols());
    t.topRows(all.rows()) = all;
    t.bottomRows(r.rows()) = r;
    all = t;
  };
  for (Index a = 0; a < x.size(); a += chunk) {
    const Index k = std::min(chunk, x.size() - a);
    add(s.push(x.segment(a, k)));
  }
  add(s.flush());
  return all;
}

}  // namespace

TEST_CASE("a sinusoid's power lands in its band; log energy is its mean square") {
  const double amp = 0.3;
  const VectorXd x = sinusoid(16000, amp, 700.0, 16000.0);  // 700 Hz: band 1 (400-1000 Hz)
  StreamingAudioFeatures s(band_options());
  const RowMatrixXd f = s.process(x);
  REQUIRE(f.rows() == 100);
  REQUIRE(f.cols() == 5);
  const double ms_db = 10.0 * std::log10(amp * amp / 2.0);
  for (Index t = 5; t < 95; ++t) {  // frames whose window is inside the signal
    CHECK(std::abs(f(t, 1) - ms_db) < 0.05);  // the main lobe (+-80 Hz) is inside the band
    CHECK(std::abs(f(t, 4) - ms_db) < 0.01);
    CHECK(f(t, 0) < ms_db - 30.0);  // the Hann sidelobes outside the band are > 30 dB down
    CHECK(f(t, 2) < ms_db - 30.0);
  }
  // frame 0 is centred on the first sample: half its window sees zeros (about half the power)
  CHECK(std::abs(f(0, 4) - (ms_db - 10.0 * std::log10(2.0))) < 0.2);
}

TEST_CASE("levinson solves the Toeplitz normal equations and recovers an AR(2) process") {
  // x_t = 1.3 x_{t-1} - 0.6 x_{t-2} + e_t: A(z) = 1 - 1.3 z^-1 + 0.6 z^-2
  std::mt19937_64 gen(20261201);
  std::normal_distribution<double> N(0.0, 1.0);
  const Index n = 200000;
  VectorXd x(n);
  x[0] = N(gen);
  x[1] = N(gen);
  for (Index t = 2; t < n; ++t) x[t] = 1.3 * x[t - 1] - 0.6 * x[t - 2] + N(gen);
  const VectorXd r = autocorrelation(x, 4);
  const LpcFit fit = levinson(r, 4);
  CHECK(fit.a[0] == 1.0);
  CHECK(std::abs(fit.a[1] + 1.3) < 0.01);
  CHECK(std::abs(fit.a[2] - 0.6) < 0.01);
  CHECK(std::abs(fit.a[3]) < 0.01);
  CHECK(std::abs(fit.a[4]) < 0.01);
  CHECK(fit.err / n == doctest::Approx(1.0).epsilon(0.02));  // the innovation variance
  // the normal equations R a = -r (with the white-noise correction on the diagonal)
  Eigen::MatrixXd R(4, 4);
  for (Index i = 0; i < 4; ++i)
    for (Index j = 0; j < 4; ++j) R(i, j) = i == j ? r[0] * (1.0 + kLpcWhiteNoise) + kLpcEnergyFloor : r[std::abs(i - j)];
  const VectorXd sol = R.ldlt().solve(-r.segment(1, 4));
  CHECK((sol - fit.a.tail(4)).norm() < 1e-10 * sol.norm());
}

TEST_CASE("autocorrelation equals its definition") {
  VectorXd x(5);
  x << 1.0, -2.0, 0.5, 3.0, 0.0;
  const VectorXd r = autocorrelation(x, 2);
  CHECK(r[0] == doctest::Approx(1 + 4 + 0.25 + 9));
  CHECK(r[1] == doctest::Approx(-2 - 1 + 1.5 + 0));
  CHECK(r[2] == doctest::Approx(0.5 - 6 + 0));
}

TEST_CASE("the cepstrum of a one-pole model is rho^n / n") {
  const double rho = 0.8;
  VectorXd a(2);
  a << 1.0, -rho;
  const VectorXd c = lpc_cepstrum(a, 2.0, 12);
  CHECK(c[0] == doctest::Approx(std::log(2.0)));
  for (Index n = 1; n < 12; ++n) CHECK(c[n] == doctest::Approx(std::pow(rho, n) / n).epsilon(1e-12));
}

TEST_CASE("formant candidates recover known resonances") {
  const double fs = 11000.0;
  // three resonances (F, B) and a real pole: A(z) = product of the sections
  const double F[3] = {3000.0, 700.0, 1800.0}, B[3] = {200.0, 80.0, 120.0};
  VectorXd a = VectorXd::Ones(1);
  auto mul = [&a](const VectorXd& s) {
    VectorXd out = VectorXd::Zero(a.size() + s.size() - 1);
    for (Index i = 0; i < a.size(); ++i)
      for (Index j = 0; j < s.size(); ++j) out[i + j] += a[i] * s[j];
    a = out;
  };
  for (int i = 0; i < 3; ++i) {
    const double r = std::exp(-kPi * B[i] / fs), th = 2.0 * kPi * F[i] / fs;
    VectorXd s(3);
    s << 1.0, -2.0 * r * std::cos(th), r * r;
    mul(s);
  }
  VectorXd real(2);
  real << 1.0, -0.5;
  mul(real);
  double f[5], b[5];
  formant_candidates(a, fs, 90.0, 1000.0, 50.0, 5, f, b);
  CHECK(f[0] == doctest::Approx(700.0).epsilon(1e-10));
  CHECK(f[1] == doctest::Approx(1800.0).epsilon(1e-10));
  CHECK(f[2] == doctest::Approx(3000.0).epsilon(1e-10));
  CHECK(b[0] == doctest::Approx(80.0).epsilon(1e-9));
  CHECK(b[1] == doctest::Approx(120.0).epsilon(1e-9));
  CHECK(b[2] == doctest::Approx(200.0).epsilon(1e-9));
  CHECK(std::isnan(f[3]));  // the real pole is no formant
  // a bandwidth limit below 100 Hz keeps only F = 700 Hz
  formant_candidates(a, fs, 90.0, 100.0, 50.0, 5, f, b);
  CHECK(f[0] == doctest::Approx(700.0).epsilon(1e-10));
  CHECK(std::isnan(f[1]));
}

TEST_CASE("the polyphase resampler equals the dense upsample-filter-downsample definition") {
  const Index up = 11, down = 16;
  std::mt19937_64 gen(7);
  std::normal_distribution<double> N(0.0, 1.0);
  // any odd-length filter: the definition does not depend on its shape
  const Index half_len = 10 * down;
  VectorXd h(2 * half_len + 1);
  for (Index i = 0; i < h.size(); ++i) h[i] = N(gen);
  const Index n = 3001;
  VectorXd x(n);
  for (Index i = 0; i < n; ++i) x[i] = N(gen);
  // dense: zero-pad h in front by n_pre_pad, y = (upsampled x) * h, subsample, drop pre_remove
  const Index n_pre_pad = down - half_len % down, pre_remove = (half_len + n_pre_pad) / down;
  VectorXd hp = VectorXd::Zero(n_pre_pad + h.size());
  hp.tail(h.size()) = h;
  const Index n_out = (n * up + down - 1) / down;
  VectorXd ref(n_out);
  for (Index j = 0; j < n_out; ++j) {
    const Index g = (j + pre_remove) * down;
    double acc = 0.0;
    for (Index m = 0; m < hp.size(); ++m) {
      const Index u = g - m;
      if (u >= 0 && u % up == 0 && u / up < n) acc += hp[m] * x[u / up];
    }
    ref[j] = acc;
  }
  for (Index chunk : {Index(1), Index(7), Index(500), n}) {
    PolyphaseResampler r(up, down, h);
    std::vector<double> out;
    for (Index a = 0; a < n; a += chunk) r.push(x.data() + a, std::min(chunk, n - a), out);
    r.flush(out);
    REQUIRE(static_cast<Index>(out.size()) == n_out);
    double err = 0.0;
    for (Index j = 0; j < n_out; ++j) err = std::max(err, std::abs(out[static_cast<size_t>(j)] - ref[j]));
    CHECK(err < 1e-12);
  }
  CHECK_THROWS_AS(PolyphaseResampler(11, 16, VectorXd::Ones(4)), std::invalid_argument);
  CHECK_THROWS_AS(PolyphaseResampler(0, 16, h), std::invalid_argument);
}

TEST_CASE("the formant tracker follows the planted path and interpolates through gaps") {
  VectorXd ref(3);
  ref << 550.0, 1650.0, 2750.0;
  FormantTracker tr(ref, 5, -1);
  std::vector<double> out;
  // frame 0 and 3: F1..F3 plus a spurious candidate at 4000 Hz; frames 1-2 have no formants
  const double good0[5] = {500.0, 1500.0, 2500.0, 4000.0, kNaN};
  const double good3[5] = {620.0, 1620.0, 2720.0, 4000.0, kNaN};
  const double none[5] = {kNaN, kNaN, kNaN, kNaN, kNaN};
  const double bw[5] = {50.0, 60.0, 70.0, 80.0, kNaN};
  tr.push(good0, bw, out);
  tr.push(none, bw, out);
  tr.push(none, bw, out);
  CHECK(out.size() <= 3);  // the gap waits for its right end
  tr.push(good3, bw, out);
  tr.finish(out);
  REQUIRE(out.size() == 12);
  CHECK(out[0] == 500.0);
  CHECK(out[2] == 2500.0);
  CHECK(out[3] == doctest::Approx(540.0));  // linear: 500 + (620 - 500) / 3
  CHECK(out[4] == doctest::Approx(1540.0));
  CHECK(out[6] == doctest::Approx(580.0));
  CHECK(out[9] == 620.0);
  CHECK(out[11] == 2720.0);
  // no formant at all: the reference values
  FormantTracker t2(ref, 5, -1);
  std::vector<double> o2;
  t2.push(none, bw, o2);
  t2.push(none, bw, o2);
  t2.finish(o2);
  REQUIRE(o2.size() == 6);
  CHECK(o2[0] == 550.0);
  CHECK(o2[5] == 2750.0);
  // a bound on the wait: with max_delay 0 every frame is out after its own push
  FormantTracker t3(ref, 5, 0);
  std::vector<double> o3;
  t3.push(good0, bw, o3);
  t3.force(o3);
  t3.push(none, bw, o3);
  t3.force(o3);
  CHECK(o3.size() == 6);
  CHECK(o3[3] == 500.0);  // the gap holds the last value
  CHECK_THROWS_AS(FormantTracker(ref, 2, -1), std::invalid_argument);
}

TEST_CASE("the stream gives the same frames for any chunking; bad input is refused") {
  AudioFeatureOptions o = band_options();
  o.features = {"log_energy", "lpc_cepstra", "lpc", "bands"};
  o.lpc_window = VectorXd::Ones(400);
  for (Index i = 0; i < 400; ++i) o.lpc_window[i] = 0.54 - 0.46 * std::cos(2.0 * kPi * i / 399.0);
  o.lpc_order = 12;
  o.n_lpc_cepstra = 8;
  o.fps = 29.97;
  std::mt19937_64 gen(3);
  std::normal_distribution<double> N(0.0, 0.1);
  VectorXd x = sinusoid(20000, 0.2, 300.0, 16000.0);
  for (Index i = 0; i < x.size(); ++i) x[i] += N(gen);
  x.segment(6000, 4000).setZero();  // a silence gap
  StreamingAudioFeatures s(o);
  REQUIRE(s.n_features() == 1 + 8 + 12 + 4);
  const RowMatrixXd whole = s.process(x);
  CHECK(whole.rows() == static_cast<Index>(std::ceil(20000 * 29.97 / 16000.0)));
  CHECK(whole.allFinite());
  for (Index chunk : {Index(1), Index(13), Index(160), Index(5000)}) {
    const RowMatrixXd got = push_in_chunks(s, x, chunk);
    REQUIRE(got.rows() == whole.rows());
    CHECK((got - whole).cwiseAbs().maxCoeff() == 0.0);  // the same operations in the same order
  }
  CHECK(s.flush().rows() == 0);  // nothing pushed: no frames
  // frames past the end see zeros: process(total) pads with silence
  const RowMatrixXd longer = s.process(x, whole.rows() + 5);
  CHECK((longer.topRows(whole.rows()) - whole).cwiseAbs().maxCoeff() == 0.0);
  CHECK(longer(whole.rows() + 4, 0) == doctest::Approx(-100.0));  // silence: the power floor
  s.push(x);
  CHECK_THROWS_AS(s.flush(3), std::invalid_argument);  // below the frames computed
  s.reset();
  VectorXd bad = x.head(10);
  bad[3] = kNaN;
  CHECK_THROWS_AS(s.push(bad), std::invalid_argument);
  AudioFeatureOptions wrong = o;
  wrong.parseval = VectorXd::Ones(3);
  CHECK_THROWS_AS(StreamingAudioFeatures{wrong}, std::invalid_argument);
  wrong = o;
  wrong.features = {"f0"};
  CHECK_THROWS_AS(StreamingAudioFeatures{wrong}, std::invalid_argument);
}
