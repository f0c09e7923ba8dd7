#pragma once
/// @file puppet.hpp
/// The voice puppet (Voice Puppetry §4.4–4.5): everything needed to turn audio feature frames
/// into facial landmarks, read from a puppet file (puppet_io.hpp), with no Python involved.
///
/// Analysis and synthesis, per face part (one part, or upper and lower face, §5.1):
///   raw features [T, A] ─ standardise ─► vocal log densities [T, N] (of the projection
///   of the standardised features, if the file has one) ─ Viterbi (or forward-
///   backward posteriors) ─► facial states ─ resample to the output rate ─► closed-form
///   trajectory (trajectory.hpp) ─► face coordinates [T', K_p] ─► shape (mean + basis) ─► pose
///   (the training mean pose) ─► pixel landmarks [T', 2P] (x0, y0, x1, y1, ...).
///
/// Arrays of the puppet file read here (N states, A audio columns, P points, K_p coordinates of
/// part p; the metadata JSON is for tools and is not interpreted by C++):
///   fps [1]                           training (analysis) frame rate
///   audio/delta_width [1] (int)       w: append regression deltas over ±w frames (0: none;
///                                     absent in older files means 0)
///   audio/mean [A'], audio/std [A']   standardisation of [features, deltas] (A' = A or 2A)
///   audio/projection [C·(2k+1), V]    optional (Python's vocal_features="projected"): the vocal
///   audio/projection_offset [V]       features are v_t = [z_{t−k}, …, z_{t+k}] · projection +
///   audio/projection_context [1] (int) offset, z the first C = audio/projection_columns [1] (int)
///   audio/projection_columns [1] (int) standardised columns, edge frames repeated (k ≤ 100);
///                                     absent: v = the standardised features (V = A')
///   face/mean_shape [P, 2]            normalised mean shape
///   face/mean_pose [4]                (log s, θ, tx, ty): pixel = s·R(θ)·shape + t
///   face/part{p}/points [P_p] (int)   the part's point indices (the parts partition the points)
///   face/part{p}/basis [K_p, 2P_p]    orthonormal rows; shape_p = mean_p + y · basis
///   hmm/part{p}/startprob [N], hmm/part{p}/transmat [N, N]
///   hmm/part{p}/face_means [N, 2K_p]  [pose, velocity] means
///   hmm/part{p}/face_covars [N, 2K_p, 2K_p]
///   hmm/part{p}/vocal_means [N, V]
///   hmm/part{p}/vocal_covars [N, V, V] (full; a tied model, Python's
///                                     vocal_covariance="tied", is N equal copies) or [N, V] (diagonal)
///   guide/map [C_g·(2k_g+1), K]       optional (Python's guide="ridge"): a prediction of the face
///   guide/offset [K]                  from ±k_g frames of audio, ŷ_t = [z_{t−k}, …, z_{t+k}] · map
///   guide/context [1] (int)           + offset (z the first C_g = guide/columns standardised
///   guide/columns [1] (int)           columns, edges repeated, k_g ≤ 100, as the projection),
///   guide/covariance [K, K]           used as evidence in the trajectory solve with precision
///   guide/weight [1]                  λ R⁻¹ (R = guide/covariance, the covariance of the
///                                     prediction's cross-fitted residuals; λ = guide/weight ≥ 0);
///                                     K = all parts' face dims, part p uses its columns of ŷ and
///                                     the marginal R[sl_p, sl_p], floored by
///                                     kGuideCovarianceFloor · (its mean variance, or 1 if 0) on
///                                     the diagonal.
///                                     A file with a guide is format version 2 or later (puppet_io.hpp).

#include "voicepuppet/adapt.hpp"
#include "voicepuppet/hmm_gaussian.hpp"
#include "voicepuppet/puppet_io.hpp"
#include "voicepuppet/trajectory.hpp"
#include "voicepuppet/types.hpp"

#include <string>
#include <vector>

namespace voicepuppet {

using IndexMatrix = Eigen::Matrix<Index, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

/// One face part: its points, shape basis and the facial/vocal HMM sharing one state machine.
struct PuppetPart {
  VectorXi points;            ///< #P_p point indices
  RowMatrixXd mean_shape;     ///< #P_p by 2
  RowMatrixXd basis;          ///< #K_p by 2·P_p
  VectorXd startprob;         ///< #N
  RowMatrixXd transmat;       ///< #N by #N
  RowMatrixXd face_means;     ///< #N by 2·K_p
  RowMatrixXd face_covars;    ///< #N·2K_p by 2K_p
  RowMatrixXd vocal_means;    ///< #N by #V
  RowMatrixXd vocal_covars;   ///< full: #N·V by V; diagonal: #N by V
  CovarianceType vocal_type = CovarianceType::Full;
  Index n_states() const { return startprob.size(); }
  Index n_dims() const { return basis.rows(); }
};

/// Regression deltas d_t = Σ_{k=1..w} k (x_{t+k} − x_{t−k}) / (2 Σ k²), frames beyond the ends
/// repeating the first or last frame; returns [x, d] side by side (#T by 2·#A), or x if w = 0.
RowMatrixXd append_deltas(const MatrixRef& x, Index width);

/// Relative floor added to the diagonal of each part's guide covariance R[sl, sl] (times its
/// mean variance, or 1 if that is 0) before its Cholesky factor gives the precision, so that it
/// is positive definite.
constexpr double kGuideCovarianceFloor = 1e-9;

/// A linear map of ±k frames of context: out_t = [z_{t−k}, …, z_{t+k}] · map + offset, z the
/// first `columns` columns of x, frames beyond the ends repeating the first or last frame (the
/// vocal projection and the guide of a puppet file).
struct ContextMap {
  RowMatrixXd map;  ///< #columns·(2·context+1) by #outputs (empty: no map)
  VectorXd offset;  ///< #outputs
  Index context = 0, columns = 0;
  bool empty() const { return map.size() == 0; }
  /// #T by #outputs for x #T by (≥ columns) (one whole sequence).
  RowMatrixXd apply(const MatrixRef& x) const;
};

struct AnimateOptions {
  double fps = 0;          ///< output frame rate; 0: the puppet's own rate
  bool posterior = false;  ///< posterior-weighted synthesis (§5) instead of the Viterbi path
  /// Test-time adaptation of the vocal features (the standardised features, or their projection
  /// if the puppet has one) to each part's vocal HMM (adapt.hpp)
  /// before decoding; kind None (the default) decodes them as they are.
  AdaptOptions adapt;
  /// λ of the guide's evidence (puppet files with a guide): negative or NaN: the file's
  /// guide/weight; 0: Brand's unguided solve. A positive value needs a guided puppet.
  double guide_weight = -1;
};

struct AnimateResult {
  RowMatrixXd points;      ///< #T' by 2P pixel landmarks at the output rate
  RowMatrixXd face;        ///< #T' by K face coordinates (parts side by side)
  IndexMatrix states;      ///< #T by #parts Viterbi states at the analysis rate
  double log_likelihood = 0;  ///< Viterbi log p(path, audio), or log p(audio) with posterior
                              ///< (with adaptation: of the adapted features, plus T log|det A|)
  std::vector<FeatureTransform> transforms;  ///< per part, with adaptation (empty without)
};

class Puppet {
 public:
  /// Validates the metadata (UTF-8, nesting, limits.hpp) and every array before it is used:
  /// shapes that agree with each other, finite values, sizes, the frame rate and the mean pose
  /// in the ranges of limits.hpp, probabilities non-negative and summing to 1, orthonormal
  /// bases, symmetric positive definite covariances, and every state's mean face within
  /// ±kMaxPixel pixels.
  /// @throws std::invalid_argument naming the array or field, its value and what was expected.
  explicit Puppet(PuppetFile file);
  /// Reads and validates a .vpp file (puppet_io.hpp errors for unreadable or corrupt files).
  static Puppet load(const std::string& path);

  double fps() const { return fps_; }
  /// Raw audio feature columns A the puppet is animated from.
  Index n_features() const { return audio_mean_.size() / (delta_width_ > 0 ? 2 : 1); }
  Index delta_width() const { return delta_width_; }
  Index n_points() const { return mean_shape_.rows(); }
  Index n_parts() const { return static_cast<Index>(parts_.size()); }
  Index n_dims() const;  ///< K, all parts
  const PuppetPart& part(Index p) const;
  const PuppetFile& file() const { return file_; }
  const VectorXd& mean_pose() const { return mean_pose_; }

  /// ([raw, deltas] − mean) / std; #T by #A'. @throws std::invalid_argument on a column
  /// mismatch or NaN.
  RowMatrixXd standardize(const MatrixRef& raw) const;
  /// Whether the vocal features are a projection of the standardised ones (audio/projection).
  bool projected() const { return !projection_.empty(); }
  /// k: frames of audio on each side the projection reads (0 without a projection).
  Index projection_context() const { return projection_.context; }
  /// C: the leading standardised columns the projection reads (0 without a projection).
  Index projection_columns() const { return projection_.columns; }
  /// The projection #C·(2k+1) by #V and its offset #V (empty without a projection).
  const RowMatrixXd& projection() const { return projection_.map; }
  const VectorXd& projection_offset() const { return projection_.offset; }
  /// The frames of delta look-ahead the vocal features need: the delta width, or 0 when they
  /// are a projection of the features alone (C <= A, as Python's vocal_features="projected"
  /// trains them with context), which never reads the deltas.
  Index vocal_delta_width() const {
    return projected() && projection_.columns <= n_features() ? 0 : delta_width_;
  }
  /// V, the vocal features' dimension.
  Index n_vocal() const { return projected() ? projection_.map.cols() : audio_mean_.size(); }
  /// The vocal features of standardised frames #T by #A' (one whole sequence: the context
  /// repeats its first and last frame): the projection if there is one, else a copy; #T by #V.
  /// @throws std::invalid_argument on a column mismatch.
  RowMatrixXd project(const MatrixRef& standardized) const;
  /// Whether the file has a guide (guide/map ...): a prediction of the face from audio used as
  /// evidence in the trajectory solve.
  bool guided() const { return !guide_.empty(); }
  /// k_g, C_g, the map #C_g·(2k_g+1) by #K and offset #K of the guide (0 / empty without one).
  Index guide_context() const { return guide_.context; }
  Index guide_columns() const { return guide_.columns; }
  const RowMatrixXd& guide_map() const { return guide_.map; }
  const VectorXd& guide_offset() const { return guide_.offset; }
  /// λ, the file's guide/weight (0 without a guide).
  double guide_weight() const { return guide_weight_; }
  /// R #K by #K as stored (empty without a guide).
  const Eigen::MatrixXd& guide_covariance() const { return guide_covariance_; }
  /// R[sl_p, sl_p]⁻¹ of part p (floored, from its Cholesky factor), #K_p by #K_p, without λ.
  const Eigen::MatrixXd& guide_precision(Index p = 0) const;
  /// The guide's prediction ŷ #T by #K of standardised frames #T by #A' (one whole sequence,
  /// edges repeated) at the puppet's rate. @throws std::invalid_argument without a guide or on
  /// a column mismatch.
  RowMatrixXd guide_predict(const MatrixRef& standardized) const;
  /// log N(v_t; vocal Gaussian of state n) of part p, v = project(standardized) for standardised
  /// frames #T by #A' of one sequence; #T by #N.
  RowMatrixXd vocal_log_density(const MatrixRef& standardized, Index p = 0) const;
  /// The trajectory blocks of part p for synthesis at `out_fps` (0: the puppet's rate).
  TrajectoryModel trajectory_model(double out_fps = 0, Index p = 0) const;
  /// Face coordinates #T by K → pixel landmarks #T by 2P at the mean training pose.
  RowMatrixXd to_points(const MatrixRef& face) const;

  /// Analysis and synthesis from raw audio feature frames at the puppet's rate.
  /// @throws std::invalid_argument on a column mismatch, an output rate outside [kMinFps,
  /// kMaxFps], more than kMaxFrames input or output frames, or landmarks beyond ±kMaxPixel
  /// (limits.hpp; animate_states likewise).
  AnimateResult animate(const MatrixRef& raw_features, const AnimateOptions& options = {}) const;
  /// The face coordinates (#T' by K) animate(raw_features, options) gives at each λ of
  /// `guide_weights` (options.guide_weight is not used; each λ as AnimateOptions::guide_weight,
  /// so negative is the file's): the audio decoded once, the trajectory solved once per λ. What
  /// choosing λ needs (the training's cross-validation).
  std::vector<RowMatrixXd> animate_faces(const MatrixRef& raw_features, const std::vector<double>& guide_weights,
                                         const AnimateOptions& options = {}) const;
  /// Synthesis from given (e.g. edited) states #T by #parts at `states_fps`, unguided (Brand's
  /// solve: there is no audio to guide it).
  AnimateResult animate_states(const Eigen::Ref<const IndexMatrix>& states, double states_fps,
                               double out_fps = 0) const;
  /// Synthesis from given (e.g. edited) states, with the guide's evidence from the audio they go
  /// with (raw feature frames at the puppet's rate, as animate takes): the states replace the
  /// Viterbi path and nothing else changes, so the states animate(raw_features, options) decoded
  /// give its face exactly, and an edit changes the face only around the frames it touches.
  /// options.fps and options.guide_weight as in animate; options.posterior and options.adapt
  /// must be off (given states are not decoded). The states must cover the audio's frames at
  /// the output rate to within one frame (the last state is held, or the extra cut).
  /// @throws std::invalid_argument on bad states, options or lengths.
  AnimateResult animate_states(const Eigen::Ref<const IndexMatrix>& states, double states_fps,
                               const MatrixRef& raw_features, const AnimateOptions& options = {}) const;

 private:
  double out_rate(double fps) const;
  /// Throws unless every state's mean face (at the mean pose) lies within ±kMaxPixel.
  void check_state_faces() const;
  /// Throws std::invalid_argument unless every coordinate of an animation's pixel landmarks is
  /// finite and within ±kMaxPixel.
  void check_reach(const RowMatrixXd& points) const;
  void read_guide(Index n_columns);
  /// λ for an AnimateOptions::guide_weight (negative/NaN: the file's), validated.
  double guide_lambda(double weight) const;
  /// animate's analysis: every part's decoding of the audio, and the guide's prediction.
  struct Analysis {
    double out = 0;                         ///< the output rate
    std::vector<VectorXi> paths;            ///< per part, the Viterbi path (analysis rate)
    std::vector<RowMatrixXd> posteriors;    ///< per part, with options.posterior
    RowMatrixXd guide_y;                    ///< ŷ at the output rate (a guided puppet)
    AnimateResult result;                   ///< states, log-likelihood and transforms
  };
  Analysis analyse(const MatrixRef& raw_features, const AnimateOptions& options, bool guide) const;
  /// animate's synthesis: the face coordinates from `a` with the guide's evidence at λ.
  RowMatrixXd synthesise(const Analysis& a, double lambda) const;
  /// The guide's prediction ŷ of standardised frames at the output rate `out` (interpolated as
  /// resample_weights).
  RowMatrixXd guide_at(const RowMatrixXd& standardized, double out) const;
  /// Given states checked against the parts: #T ≥ 1 rows, one column per part, each in range,
  /// states_fps in [kMinFps, kMaxFps], and at most kMaxFrames of them at the output rate `out`.
  void check_states(const Eigen::Ref<const IndexMatrix>& states, double states_fps, double out) const;
  /// The frames n audio feature frames give at the output rate `out`, both checked to be in
  /// [1, kMaxFrames] (limits.hpp) before anything is allocated from them.
  Index out_frames(Index n, double out) const;
  PuppetFile file_;
  double fps_ = 0;
  Index delta_width_ = 0;
  VectorXd audio_mean_, audio_std_, mean_pose_;
  ContextMap projection_;  ///< #C·(2k+1) by #V, empty without a projection
  ContextMap guide_;       ///< #C_g·(2k_g+1) by #K, empty without a guide
  Eigen::MatrixXd guide_covariance_;
  std::vector<Eigen::MatrixXd> guide_precision_;  ///< per part, without λ
  double guide_weight_ = 0;
  RowMatrixXd mean_shape_;
  std::vector<PuppetPart> parts_;
  std::vector<TrajectoryModel> native_;  ///< trajectory blocks at the puppet's own rate
};

}  // namespace voicepuppet
