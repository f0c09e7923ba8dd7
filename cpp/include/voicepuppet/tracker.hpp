#pragma once
/// @file tracker.hpp
/// The spring-mesh SSD facial tracker of Voice Puppetry §4.1: one sub-pixel SSD texture tracker
/// per landmark (inverse-compositional Lucas–Kanade, translation only, on an image pyramid),
/// all of them coupled by springs along the edges of a mesh and relaxed jointly: one
/// Gauss–Newton system over all 2·P coordinates per iteration, so a tracker that loses its
/// texture (occlusion, blur) is carried by its neighbours and re-locks when the texture returns.
///
/// Drift: every frame is first tracked against each point's current template, then refined
/// against its first-frame template; the current template is replaced only when both answers
/// agree (the guarded update of Matthews, Ishikawa & Baker, "The template update problem", 2004).
/// The joint system is block-sparse (2×2 blocks, one coupling per spring) and is solved by
/// block-Jacobi preconditioned conjugate gradients.
///
/// Residuals are brightness-normalised (the sampled patch is scaled to the template's mean and
/// contrast), and each point's data term is weighted by its normalised cross-correlation with
/// the template, so lighting drift does not move points and occluded points hand over to the
/// springs. Springs are scalar-length springs: energy k·(|p_j − p_i| − L)², with L and k
/// re-estimated from the mean and variance of the tracked distances (`estimate_springs`).
///
/// Lips: a point beside a region whose appearance changes (a lip beside the opening mouth) can
/// be tracked on one half of its patch (`TrackerOptions::patch_sides`), and such points are
/// searched for exhaustively when the gradient steps lose them (`TrackerOptions::search_radius`),
/// alone or as a group (`search_groups`: a lower lip). Offset springs (`SpringMesh`) hold the
/// vector between two points in the face frame, so points on a contour do not slide along it,
/// and a point whose data contradict such springs by many standard deviations is handed to them
/// for the frame (`spring_outlier`).
///
/// Head pose: with `TrackerOptions::frame_points`, each frame's similarity A (rotation and
/// scale of those points from the first frame to the previous frame, fitted robustly) is the
/// face frame. The first-frame templates are re-cut from the first frame seen through A (so
/// they look as the face does now), half patches and sided searches turn with it, search radii
/// and spring rest lengths scale with it; the Lucas–Kanade steps stay per-point translations,
/// since the warp is known rather than estimated per patch. Without frame points nothing of
/// this happens (the image frame).
///
/// Images come in as plain 8-bit grey buffers (`GreyImage`); `tracker_opencv.hpp` adapts a
/// `cv::Mat` for C++ callers who use OpenCV. Coordinates are pixels, (x, y), the centre of the
/// top-left pixel at (0, 0).

#include "voicepuppet/types.hpp"

#include <cstdint>
#include <memory>
#include <vector>

namespace voicepuppet {

/// A read-only view of an 8-bit grey image: `height` rows of `width` bytes, rows `stride`
/// bytes apart (stride >= width). The tracker never keeps the pointer past a call.
struct GreyImage {
  const std::uint8_t* data = nullptr;
  Index width = 0;
  Index height = 0;
  Index stride = 0;
};

/// #E by 2 vertex index pairs (i < j), one per spring.
using EdgeMatrix = Eigen::Matrix<Index, Eigen::Dynamic, 2, Eigen::RowMajor>;
/// Row-major boolean matrix (e.g. #T by #P lost flags).
using RowMatrixXb = Eigen::Matrix<bool, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using VectorXb = Eigen::Matrix<bool, Eigen::Dynamic, 1>;

/// The springs between trackers.
///
/// Besides its length spring, an edge can carry an *offset spring*: a Gaussian on the vector
/// p_j − p_i seen in the face frame, energy (f − μ_e)ᵀ Λ_e (f − μ_e) with f = A⁻¹ (p_j − p_i),
/// A the similarity (rotation and scale) that maps the first frame's `frame_points` to the
/// previous frame's (identity without frame points). Unlike a length spring it can be soft in
/// one direction and stiff in the other: a lip opens along the face's vertical axis by many
/// pixels but barely slides along its contour, which a length spring cannot tell apart.
struct SpringMesh {
  EdgeMatrix edges;      ///< #E by 2 point indices
  /// #E rest lengths L_e in face-frame pixels (> 0): the first frame's pixels, scaled with
  /// the face's scale s when the tracker follows the head pose (image pixels without frame points)
  VectorXd rest_length;
  /// #E stiffnesses k_e in 1/(face-frame px)² (>= 0), energy k_e·(|p_j − p_i| / s − L_e)²
  VectorXd stiffness;
  /// #E by 4 offset-spring precisions Λ_e (row-major 2×2, symmetric positive semidefinite,
  /// 1/px²; a zero row: no offset spring on that edge), or empty (none at all)
  RowMatrixXd offset_precision;
  /// #E by 2 mean offsets μ_e (face-frame px) of the offset springs, or empty with
  /// `offset_precision`
  RowMatrixXd offset_mean;
};

/// Edges of the Delaunay triangulation of 2D points (Bowyer–Watson, O(P²), fine for the few
/// dozen points of a face mesh), each as (i, j) with i < j, sorted lexicographically.
/// @param[in] points  #P by 2 (x, y), P >= 3, finite, pairwise distinct, not all collinear
/// @throws std::invalid_argument on a wrong shape, fewer than 3 points, non-finite or
///         duplicate points, or points that are all on one line (no triangle exists).
EdgeMatrix delaunay_edges(const MatrixRef& points);

/// Springs along `edges` whose rest lengths are the distances between `points` and whose
/// stiffness is 1 / max(relative_sigma · L_e, min_sigma)²: the initial mesh, before any
/// re-estimation. The floor keeps short springs (the few pixels across closed lips) from
/// being so stiff that they hold the points at rest when the mouth opens.
/// @param[in] points          #P by 2 (x, y)
/// @param[in] edges           #E by 2 indices into points, i != j
/// @param[in] relative_sigma  assumed standard deviation of each length, as a fraction of it (> 0)
/// @param[in] min_sigma       floor on that standard deviation in pixels (>= 0)
/// @throws std::invalid_argument on bad shapes, indices, coincident endpoints or sigmas.
SpringMesh springs_from_points(const MatrixRef& points, const EdgeMatrix& edges,
                               double relative_sigma = 0.05, double min_sigma = 0.0);

/// Re-estimates spring rest lengths and stiffnesses from a tracked pass (paper §4.1): for each
/// edge, L_e = mean and k_e = 1 / max(var, min_sigma²) of the distance between its endpoints over
/// the frames where neither endpoint is lost and the distance lies within 3 robust standard
/// deviations (1.4826 · MAD, at least min_sigma) of its median, so frames where a tracker sat on
/// the wrong feature do not soften the spring that should pull it back. Edges with fewer than
/// 2 such frames keep their previous values. An edge with an offset spring gets, over the same
/// frames, μ_e = the mean face-frame offset and Λ_e = the inverse of its covariance (eigenvalues
/// floored at min_sigma²); its length spring is then switched off (k_e = 0), since the offset
/// spring already holds the length's statistics. With `frame_points`, distances are measured
/// in each frame's face frame (divided by the face's scale), as the tracker uses them.
/// @param[in] tracks     #T by 2·#P positions, row t = (x0, y0, x1, y1, ...) of frame t
/// @param[in] lost       #T by #P lost flags (true: exclude from the statistics)
/// @param[in] previous   the mesh used for the pass (its edges are kept)
/// @param[in] min_sigma  floor on the distance standard deviation in pixels (> 0)
/// @param[in] frame_points  indices of the points that define the face frame of each frame
///                     (similarity to frame 0, see `SpringMesh`; of those not lost in that frame,
///                     and robust to the ones that slid off, as in the tracker); empty: the
///                     image frame
/// @throws std::invalid_argument on shape mismatches, non-finite tracks or a bad floor.
SpringMesh estimate_springs(const MatrixRef& tracks, const RowMatrixXb& lost,
                            const SpringMesh& previous, double min_sigma = 0.5,
                            const VectorXi& frame_points = VectorXi());

/// The similarity A (2×2: rotation and scale, [[a, −b], [b, a]]) that best maps the centred
/// `from` rows `idx` onto the centred `to` rows in least squares (the identity for an empty
/// `idx` or when `from` has no spread).
/// @param[in] from, to  #P by 2 point sets
/// @param[in] idx       indices into both (>= 2 of them, or empty)
Eigen::Matrix2d face_similarity(const MatrixRef& from, const MatrixRef& to, const VectorXi& idx);

/// Tuning of `SpringMeshTracker`. Defaults suit faces at 100–700 px across.
struct TrackerOptions {
  Index patch_radius = 6;        ///< patch is (2r+1)² pixels at every pyramid level (>= 1)
  Index levels = 3;              ///< pyramid levels (>= 1; fewer are used on small frames)
  Index max_iterations = 5;      ///< Gauss–Newton iterations per level and stage (>= 1)
  double tolerance = 0.02;       ///< stop the finest level when no point moves more (px, > 0);
                                 ///< coarser levels stop at max(tolerance, 0.1) level pixels
  double intensity_sigma = 8.0;  ///< grey-level noise of the SSD residual (> 0)
  double spring_weight = 1.0;    ///< multiplies every spring stiffness (>= 0)
  double ncc_floor = 0.5;        ///< data weight is 0 at or below this template correlation
  double ncc_full = 0.85;        ///< ... and 1 at or above this one (ncc_floor < ncc_full <= 1)
  double lost_confidence = 0.5;  ///< a point is lost when its confidence is below this
  double drift_tolerance = 1.0;  ///< px: current- and first-template answers must agree this well
                                 ///< (and the first-frame correlation reach ncc_full) for the
                                 ///< current template to be replaced (> 0)
  double damping = 1e-3;         ///< 1/px² Levenberg damping toward the previous iterate (> 0)
  /// #P by 2 half-patch directions, or empty (all points use whole patches). A non-zero row
  /// (dx, dy) makes point i's templates use only the pixels with (u·dx + v·dy) > 0, (u, v) the
  /// offset from the point: the side of a lip away from the mouth opening, whose texture moves
  /// with the point while the other side turns from closed lips into the mouth cavity.
  RowMatrixXd patch_sides;
  /// px: a half-patch point that stage A leaves correlating below `ncc_full` with its template
  /// is searched for exhaustively (whole-pixel offsets within this radius, finest level, longer
  /// moves penalised); it moves to the best offset if that correlates at least `ncc_full`, and
  /// the mesh is relaxed again (0: no search)
  double search_radius = 0.0;
  /// indices of the points whose similarity to the first frame defines the face frame (head
  /// pose): the previous frame's positions of those not lost there, so the frame is fixed
  /// within a frame's relaxation, with the points a least-median fit over pairs of them finds
  /// off (beyond 3 robust sigmas, at least 2 % of their RMS radius) left out. The offset
  /// springs (`SpringMesh`) live in it, length springs scale with it, and the first-frame
  /// templates are re-cut through it whenever it has moved by more than 0.2 px at a patch
  /// corner since they were cut (exactly the first frame's while that close to the identity);
  /// half-patch sides, reference search directions and search radii turn and scale with it.
  /// Empty: the image frame (none of this).
  VectorXi frame_points;
  /// #P group ids (-1: in no group), or empty: points searched for jointly after stage A, by a
  /// common whole-pixel offset within `group_search_radius` (each point free to deviate 2 px
  /// from it), scored by the group's mean correlation with the first-frame templates; a lower
  /// lip moves as one
  VectorXi search_groups;
  /// px: radius of the joint search of `search_groups` (0: none)
  double group_search_radius = 0.0;
  /// standard deviations: after stage A, an end of an `outlier_edges` spring whose position is
  /// further than this (Mahalanobis length of the step those springs alone would take) from
  /// where they put it has its data term muted for the rest of the frame, and the mesh is
  /// relaxed again (worst first, never two neighbours in one round, two rounds; 0: off)
  double spring_outlier = 0.0;
  /// indices into the mesh's edges of the springs the outlier check uses: those that hold
  /// whatever the face does (within one lip), not those that stretch with an expression
  VectorXi outlier_edges;
  /// indices of points searched for after stage A against their *first-frame* templates:
  /// every whole-pixel offset within `reference_search_radius` of where they are (finest
  /// level, longer moves penalised like `search_radius`'s); a point moves to the best offset
  /// when that correlates at least `reference_search_ncc` and clearly better than staying, and
  /// stage B (against the first-frame templates) refines it from there. For points whose whole
  /// patch matches a contour beside them nearly as well (a mouth corner next to the upper lip's
  /// edge), where the gradient steps and a current template that followed the contour leave them.
  VectorXi reference_points;
  /// #P by 2 directions, or empty: a reference point with a non-zero row is searched for with
  /// only the half of its first-frame patch on that side (as `patch_sides`; the outer upper lip,
  /// whose lower half turns into teeth) and only along that direction, i.e. across its contour
  /// (along it a half patch matches about equally well everywhere); its tracking is unchanged
  RowMatrixXd reference_sides;
  double reference_search_radius = 0.0;  ///< px (0: no reference search)
  double reference_search_ncc = 0.7;     ///< acceptance correlation of a reference search move
  /// #K by 2 point index pairs (upper, lower) kept in order along `order_axis` in the face
  /// frame: the lower point never above the upper one (the inner lips of a 68-point face do not
  /// cross). After every Gauss–Newton step, and on the frame's answer, a pair out of order is
  /// moved apart onto the order, equally and oppositely along the axis (its midpoint kept), so
  /// the next step's springs and data work from a mouth that is possible. Empty: no order.
  EdgeMatrix order_pairs;
  /// the face frame's direction from an upper to a lower point (the first frame's axes: from
  /// the eyes down to the mouth); non-zero, normalised by the tracker
  Eigen::Vector2d order_axis = Eigen::Vector2d(0.0, 1.0);
  /// face-frame px a lower point may lie above its upper one before the pair is moved (>= 0):
  /// closed lips whose points meet within the tracker's noise are left as they are
  double order_margin = 0.0;
  /// #P precisions (1/px², 0: none) of the per-frame anchors `track` may be given: point i
  /// adds anchor_precision[i]·|p_i − a_i|² to the mesh's energy at every Gauss–Newton step of
  /// that frame (an independent detector's answer as a soft observation beside the patches and
  /// springs). Empty: no anchors.
  VectorXd anchor_precision;
  /// #P px each point may stray from its anchor before the anchor pulls (>= 0), or empty (0 for
  /// all): the energy is then anchor_precision[i]·(|p_i − a_i| − anchor_slack[i])² beyond it and 0
  /// within, so the patches place a point within the detector's noise and the anchor only bounds
  /// their drift; 0 is a plain spring to the anchor
  VectorXd anchor_slack;
};

/// One frame's answer.
struct TrackerFrame {
  RowMatrixXd points;   ///< #P by 2 positions (x, y) in pixels
  VectorXd confidence;  ///< #P in [0, 1]: correlation of the final patch with the first-frame patch
  VectorXb lost;        ///< #P: outside the image or confidence below `lost_confidence`
  Index iterations = 0; ///< Gauss–Newton iterations spent on this frame (all levels, both stages)
};

/// The tracker: construct it on the first frame with the initial points and the springs, then
/// call `track` on every following frame in order.
class SpringMeshTracker {
 public:
  /// @param[in] first    the first frame (where `points` are given)
  /// @param[in] points   #P by 2 initial positions, P >= 3, inside the image
  /// @param[in] mesh     springs between the points (e.g. `springs_from_points(points,
  ///                     delaunay_edges(points))`)
  /// @param[in] options  tuning, see `TrackerOptions`
  /// @throws std::invalid_argument on an empty or inconsistent image, fewer than 3 points,
  ///         a point outside the image, a bad mesh or bad options.
  SpringMeshTracker(const GreyImage& first, const MatrixRef& points, const SpringMesh& mesh,
                    const TrackerOptions& options = {});
  ~SpringMeshTracker();
  SpringMeshTracker(SpringMeshTracker&&) noexcept;
  SpringMeshTracker& operator=(SpringMeshTracker&&) noexcept;

  /// Tracks the next frame (same size as the first) from the previous positions.
  /// @throws std::invalid_argument when the frame is empty or its size differs from the first.
  TrackerFrame track(const GreyImage& frame);

  /// As `track`, with this frame's anchors: #P by 2 positions (x, y), a row of NaN for a point
  /// without one, pulling with `TrackerOptions::anchor_precision`.
  /// @throws std::invalid_argument when `anchors` is not #P by 2, or holds an infinite value.
  TrackerFrame track(const GreyImage& frame, const MatrixRef& anchors);

  /// Restarts the points mid-sequence at `points` (a face found again elsewhere in the frame,
  /// e.g. after it left the frame or was covered): the current templates are reset to the
  /// first-frame ones (as the head pose currently sees them), and the per-point state of the
  /// last frame (data weights, lost flags, muted points) is cleared as on construction, so the
  /// next `track` call locks from `points` and fits the head pose to them. The first-frame
  /// templates, the springs and the options are kept. Points may lie outside the image (they
  /// are then reported lost).
  /// @param[in] points  #P by 2 finite positions (x, y) in pixels of the current frame size
  /// @throws std::invalid_argument when `points` is not #P by 2 or holds a non-finite value.
  void relocate(const MatrixRef& points);

  /// Current positions (#P by 2).
  const RowMatrixXd& points() const;
  /// Number of points, frame width and height.
  Index n_points() const;
  Index width() const;
  Index height() const;
  /// Pyramid levels actually used (the requested number, limited by the frame size).
  Index levels() const;
  const SpringMesh& mesh() const;
  const TrackerOptions& options() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Checks an image view: non-null data, positive size, stride >= width.
/// @throws std::invalid_argument naming `name`.
void check_grey_image(const GreyImage& image, const char* name);

}  // namespace voicepuppet
