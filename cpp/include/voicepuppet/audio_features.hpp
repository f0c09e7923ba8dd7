#pragma once
/// @file audio_features.hpp
/// The audio front end's per-frame work: short-time spectra (mel / MFCC, sonorant band
/// energies, log energy, RASTA-PLP), LPC and LPC cepstra, and formants (polyphase resampling,
/// LPC roots, an online continuity tracker), computed on a stream of samples pushed in chunks
/// of any size. The offline front end is the same code run on the whole signal in one push.
///
/// The analysis tables (windows, filterbanks, DCT matrix, resampler taps) come in through
/// `AudioFeatureOptions`; the Python layer (`voicepuppet.audio.stream`) builds them from the
/// definitions in `voicepuppet.audio.spectral` / `lpc`, so the two sides cannot drift apart.
/// Conventions (those of the Python front end, docs/audio.md): frame `k` is centred on sample
/// `rint(k rate / fps)`, zeros before the first sample and after the end of the stream; the
/// inverse filter is `A(z) = 1 + a_1 z^-1 + ... + a_p z^-p`.

#include <array>
#include <complex>
#include <memory>
#include <string>
#include <vector>

#include "voicepuppet/types.hpp"

namespace voicepuppet {

/// Relative white-noise correction added to lag 0 by `levinson` (-90 dB).
inline constexpr double kLpcWhiteNoise = 1e-9;
/// Absolute floor on lag 0 (silence): a flat model spectrum at -100 dB full scale.
inline constexpr double kLpcEnergyFloor = 1e-10;
/// Power floor of every log spectrum (-100 dB).
inline constexpr double kPowerFloor = 1e-10;

/// An all-pole fit: `a = [1, a_1 .. a_p]` and the prediction-error power.
struct LpcFit {
  VectorXd a;
  double err = 0.0;
};

/// Levinson-Durbin recursion (autocorrelation method) with the white-noise correction
/// `r_0 (1 + 1e-9) + 1e-10` and the error floored at 1e-13.
/// @param[in] r  #(>= order+1) autocorrelations, lag 0 first
/// @param[in] order  prediction order p >= 1
/// @throws std::invalid_argument if r is shorter than order + 1 or order < 1
LpcFit levinson(const VectorRef& r, Index order);

/// Autocorrelation `r_l = sum_j x_j x_{j+l}`, l = 0 .. max_lag (no wrap-around).
/// @param[in] frame  #n samples
/// @param[in] max_lag  largest lag (>= 0)
VectorXd autocorrelation(const VectorRef& frame, Index max_lag);

/// Cepstrum `c_0 .. c_{n_ceps-1}` of the all-pole model `err / |A|^2`:
/// `c_0 = log err`, `c_n = -a_n - sum_{k=max(1,n-p)}^{n-1} (k / n) c_k a_{n-k}`.
/// @param[in] a  #(p+1) `[1, a_1 .. a_p]`
VectorXd lpc_cepstrum(const VectorRef& a, double err, Index n_ceps);

/// Roots of `A(z)` (eigenvalues of the companion matrix), #p.
/// @param[in] a  #(p+1) `[1, a_1 .. a_p]`, p >= 1
std::vector<std::complex<double>> lpc_roots(const VectorRef& a);

/// Formant candidates of one LPC fit, ascending in frequency, NaN-padded to `n_max`.
/// A root `|r| e^{j theta}` with positive imaginary part gives `F = theta rate / (2 pi)`,
/// `B = -log|r| rate / pi`; roots below `min_freq`, within `margin` of Nyquist or wider than
/// `max_bandwidth` are dropped.
/// @param[out] freqs, bands  #n_max each
void formant_candidates(const VectorRef& a, double rate, double min_freq, double max_bandwidth,
                        double margin, Index n_max, double* freqs, double* bands);

/// `scipy.signal.resample_poly(x, up, down)` on a stream: outputs are released once every input
/// under their filter has arrived; `flush` finishes with the zero padding of the offline call, so
/// the concatenated outputs equal the offline call on the concatenated input (same length
/// `ceil(n up / down)`).
class PolyphaseResampler {
 public:
  /// @param[in] up, down  coprime factors (>= 1)
  /// @param[in] taps  #(2 h + 1) the offline filter (for resample_poly: Kaiser(5) sinc times up,
  ///   h = 10 max(up, down)); odd length
  PolyphaseResampler(Index up, Index down, const VectorRef& taps);
  /// Feed inputs; appends the outputs they complete to `out`.
  void push(const double* x, Index n, std::vector<double>& out);
  /// End of input: appends the remaining outputs, then resets.
  void flush(std::vector<double>& out);
  void reset();
  Index up() const { return up_; }
  Index down() const { return down_; }

 private:
  double output(Index g) const;  // full upfirdn index g
  void trim();
  Index up_, down_, pre_remove_;
  VectorXd h_;                     // taps with the offline pre-padding
  std::vector<std::vector<double>> phases_;  // per phase, its taps reversed
  std::vector<double> buf_;        // inputs from global index offset_
  Index offset_ = 0, n_ = 0, done_ = 0;
};

/// Online version of the formant continuity tracker (a Viterbi over increasing choices of
/// `n_formants` of the candidates; Praat's Formant Track costs with unit weights). A frame is
/// final once every surviving path agrees on it (the offline Viterbi path then agrees too);
/// frames whose chosen assignment is invalid are filled by linear interpolation once the next
/// valid frame is final (leading gaps hold the first value, trailing gaps the last, no valid
/// frame at all gives the reference values). `max_delay >= 0` forces decisions for frames
/// pending longer than that many frames (the current best path; gaps hold the last value).
class FormantTracker {
 public:
  /// @param[in] reference  #n_formants reference frequencies (Hz)
  /// @param[in] n_cand  candidates per frame (>= n_formants)
  /// @param[in] max_delay  -1: exact; else a bound in frames
  FormantTracker(const VectorRef& reference, Index n_cand, Index max_delay);
  /// One frame's candidates (#n_cand frequencies and bandwidths, NaN = none); appends
  /// finished rows (#n_formants each) to `out`.
  void push(const double* freqs, const double* bands, std::vector<double>& out);
  /// Apply max_delay (call once after a batch of pushes).
  void force(std::vector<double>& out);
  /// End of stream: the best path decides the rest.
  void finish(std::vector<double>& out);
  void reset();
  /// Frames whose output was forced by max_delay.
  Index forced() const { return forced_; }

 private:
  struct Pending {
    std::vector<double> F;  // S x n
    std::vector<char> valid;
    std::vector<Index> back;
  };
  struct Decided {
    Index frame;
    bool good;
    std::array<double, 8> v;
  };
  std::vector<Index> trace_one(Index end_state) const;
  void commit(const std::vector<Index>& states, Index k);
  void decide_converged();
  void emit(bool final, std::vector<double>& out);
  void fill_gap_to(Index frame, const double* val, std::vector<double>& out);
  void put(const double* v, std::vector<double>& out) const;

  VectorXd ref_;
  Index n_, S_, max_delay_;
  std::vector<Index> combos_;  // S x n
  std::vector<double> score_, prev_logF_, logF_, local_;
  std::vector<char> prev_valid_;
  bool started_ = false;
  Index t_ = 0, base_ = 0, out_next_ = 0, forced_ = 0;
  std::vector<Pending> pending_;
  std::vector<Decided> decided_;
  size_t decided_head_ = 0;
  bool has_last_ = false, any_good_ = false;
  Index last_frame_ = 0;
  std::array<double, 8> last_val_{};
};

/// Everything a `StreamingAudioFeatures` computes, with its tables. Sizes: `n_bins = n_fft / 2 + 1`.
struct AudioFeatureOptions {
  double rate = 16000.0;        ///< sample rate of the pushed samples (Hz, whole, >= 1)
  double fps = 29.97;           ///< output frame rate
  /// Output column blocks in order, from {"lpc", "lpc_cepstra", "rasta_plp", "mfcc",
  /// "mfcc_deltas", "formants", "bands", "log_energy"}.
  std::vector<std::string> features;

  // spectral pass (mfcc, mfcc_deltas, rasta_plp, bands, log_energy)
  Index n_fft = 0;
  VectorXd spectral_window;     ///< #n_fft, the analysis window centred in the FFT frame
  Index fine = 1;               ///< spectra on a grid `fine` times finer than the frames (RASTA)
  RowMatrixXd mel_filters;      ///< #n_mels by #n_bins
  RowMatrixXd dct;              ///< #n_mfcc by #n_mels orthonormal DCT-II rows
  Index delta_width = 2;
  RowMatrixXd band_weights;     ///< #bands by #n_bins (band indicator times Parseval weights)
  VectorXd parseval;            ///< #n_bins
  RowMatrixXd bark_filters;     ///< #n_bark by #n_bins
  VectorXd loudness;            ///< #n_bark equal-loudness weights at the band centres
  VectorXd rasta_b;             ///< #5 numerator of the RASTA filter
  double rasta_pole = 0.94;     ///< its pole at the fine frame rate
  VectorXd rasta_zi;            ///< #4 steady-state initial conditions for a unit input
  Index rasta_order = 8;
  Index n_rasta = 9;            ///< cepstra c_0 .. c_{n_rasta-1} computed
  Index rasta_first = 1;        ///< first cepstrum kept (0 keeps c_0)

  // LPC (lpc, lpc_cepstra)
  VectorXd lpc_window;          ///< #length Hamming window
  Index lpc_order = 12;
  double lpc_preemph = 0.97;
  Index n_lpc_cepstra = 12;     ///< c_1 .. c_n kept

  // formants
  Index resample_up = 1, resample_down = 1;  ///< rate -> formant rate factors
  VectorXd resample_taps;       ///< the offline resample_poly filter (empty when up == down)
  double formant_rate = 11000.0;
  VectorXd formant_window;      ///< #length Gaussian window
  Index formant_order = 10;
  double formant_preemph = 0.0;
  double formant_min_freq = 90.0;
  double formant_max_bandwidth = 1000.0;
  double formant_margin = 50.0;
  VectorXd formant_reference;   ///< #3 reference frequencies of the tracker
  Index formant_lag = -1;       ///< -1: exact; else the tracker's max_delay (frames)
};

/// The front end on a stream: push chunks of samples, get the finished feature frames.
/// Frame `k` is complete when every window it needs has arrived (and, for formants, when the
/// tracker has decided it); rows come out in order, each with all columns.
class StreamingAudioFeatures {
 public:
  /// @throws std::invalid_argument naming the option when a table has the wrong size or a
  ///   value is out of range
  explicit StreamingAudioFeatures(AudioFeatureOptions options);
  ~StreamingAudioFeatures();
  StreamingAudioFeatures(StreamingAudioFeatures&&) noexcept;
  StreamingAudioFeatures& operator=(StreamingAudioFeatures&&) noexcept;

  /// Feed a chunk (any length, including 0) of finite samples.
  /// @return #K by #n_features, the frames completed by it
  /// @throws std::invalid_argument on NaN / infinite samples (then nothing is consumed)
  RowMatrixXd push(const VectorRef& samples);
  /// End of stream: the remaining frames up to `total` in all (default, -1:
  /// `ceil(n_samples fps / rate)`, none if nothing was pushed); windows past the end see zeros.
  /// Then the stream is reset.
  /// @throws std::invalid_argument if total is below the frames already computed
  RowMatrixXd flush(Index total = -1);
  /// A whole recording in one call: push + flush(total), never emitting more than `total`
  /// frames (-1: the default count); the stream is reset before and after.
  RowMatrixXd process(const VectorRef& samples, Index total = -1);
  void reset();

  Index n_features() const;
  Index frames_out() const;
  Index samples_in() const;
  /// Frames whose formants were forced by formant_lag.
  Index formants_forced() const;
  const AudioFeatureOptions& options() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace voicepuppet
