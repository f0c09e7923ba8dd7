// Tests of a puppet file's guide (puppet.hpp: guide/*): the prediction ŷ computed by hand, the
// guided animation equal to the trajectory solve with the evidence composed by hand (at the
// puppet's rate and another), λ = 0 equal to the unguided puppet exactly, the format version
// (2 only with a guide), every bad guide array refused by name, and StreamingPuppet streaming a
// guided puppet as Puppet::animate (the two-part cases are in test_streaming.cpp).
#include <doctest/doctest.h>

#include "puppet_arrays.hpp"
#include "throws_with.hpp"

#include "voicepuppet/hmm.hpp"
#include "voicepuppet/puppet.hpp"
#include "voicepuppet/puppet_io.hpp"
#include "voicepuppet/streaming.hpp"

#include <cmath>
#include <stdexcept>
#include <string>

using namespace voicepuppet;

namespace {

using voicepuppet::testing::throws_with;

// Three points, one part with a 2-D basis, two states, two audio columns (as test_puppet.cpp's
// tiny puppet, with K = 2 so that the guide's precision is a matrix).
PuppetFile unguided() {
  PuppetFile f;
  f.metadata = R"({"kind": "test"})";
  f.arrays["fps"] = testing::arr({1}, {30});
  f.arrays["audio/mean"] = testing::arr({2}, {1, -1});
  f.arrays["audio/std"] = testing::arr({2}, {2, 0.5});
  f.arrays["face/mean_shape"] = testing::arr({3, 2}, {-1, 0, 1, 0, 0, 1});
  f.arrays["face/mean_pose"] = testing::arr({4}, {0, 0, 0, 0});
  PuppetArray pts;
  pts.dtype = PuppetArray::DType::Int64;
  pts.shape = {3};
  pts.i64 = {0, 1, 2};
  f.arrays["face/part0/points"] = pts;
  f.arrays["face/part0/basis"] = testing::arr({2, 6}, {0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0});
  f.arrays["hmm/part0/startprob"] = testing::arr({2}, {1, 0});
  f.arrays["hmm/part0/transmat"] = testing::arr({2, 2}, {0.9, 0.1, 0, 1});
  f.arrays["hmm/part0/face_means"] = testing::arr({2, 4}, {0, 0, 0, 0, 4, -1, 0, 0});
  // [pose, velocity] covariances 4 x 4 per state: diagonal plus a pose correlation
  f.arrays["hmm/part0/face_covars"] = testing::arr({2, 4, 4}, {1, 0.2, 0, 0,  0.2, 0.5, 0, 0,  0, 0, 0.1, 0,  0, 0, 0, 0.1,
                                                      0.3, 0, 0, 0,  0, 0.3, 0, 0,  0, 0, 0.1, 0,  0, 0, 0, 0.1});
  f.arrays["hmm/part0/vocal_means"] = testing::arr({2, 2}, {-1, 0, 1, 0});
  f.arrays["hmm/part0/vocal_covars"] = testing::arr({2, 2}, {0.2, 1, 0.2, 1});
  return f;
}

// The guide: ŷ_t = [z_{t−1}, z_t, z_{t+1}] (first column) · map + offset, K = 2.
PuppetFile guided(double weight = 1.0) {
  PuppetFile f = unguided();
  f.arrays["guide/context"] = testing::int_arr(1);
  f.arrays["guide/columns"] = testing::int_arr(1);
  f.arrays["guide/map"] = testing::arr({3, 2}, {0.5, 0.1, 1.0, -0.3, -0.25, 0.2});
  f.arrays["guide/offset"] = testing::arr({2}, {0.1, -0.2});
  f.arrays["guide/covariance"] = testing::arr({2, 2}, {0.4, 0.1, 0.1, 0.2});
  f.arrays["guide/weight"] = testing::arr({1}, {weight});
  return f;
}

RowMatrixXd audio() {
  RowMatrixXd raw(12, 2);
  for (Index t = 0; t < 12; ++t) {
    raw(t, 0) = 1 + 2 * (t < 6 ? -1.0 : 1.0) + 0.3 * std::sin(static_cast<double>(t));
    raw(t, 1) = -1 + 0.05 * static_cast<double>(t);
  }
  return raw;
}

}  // namespace

TEST_CASE("guide: the prediction of ±k standardised frames, and the guided animation composed by hand") {
  const Puppet p(guided(0.7));
  REQUIRE(p.guided());
  CHECK(p.guide_context() == 1);
  CHECK(p.guide_columns() == 1);
  CHECK(p.guide_weight() == 0.7);
  const RowMatrixXd raw = audio();
  const RowMatrixXd z = p.standardize(raw);
  const RowMatrixXd yhat = p.guide_predict(z);
  REQUIRE(yhat.rows() == 12);
  REQUIRE(yhat.cols() == 2);
  const double m[3][2] = {{0.5, 0.1}, {1.0, -0.3}, {-0.25, 0.2}};
  for (Index t = 0; t < 12; ++t) {
    for (Index k = 0; k < 2; ++k) {
      double want = k == 0 ? 0.1 : -0.2;
      for (Index j = -1; j <= 1; ++j) want += z(std::clamp<Index>(t + j, 0, 11), 0) * m[j + 1][k];
      CHECK(yhat(t, k) == doctest::Approx(want).epsilon(1e-14));
    }
  }
  // the precision: (R + floor·I)⁻¹, floor = kGuideCovarianceFloor · mean variance
  const double fl = kGuideCovarianceFloor * 0.3, a = 0.4 + fl, b = 0.1, c = 0.2 + fl, det = a * c - b * b;
  const Eigen::MatrixXd& prec = p.guide_precision(0);
  CHECK(prec(0, 0) == doctest::Approx(c / det).epsilon(1e-13));
  CHECK(prec(0, 1) == doctest::Approx(-b / det).epsilon(1e-13));
  CHECK(prec(1, 1) == doctest::Approx(a / det).epsilon(1e-13));

  const auto& pt = p.part(0);
  const VectorXi no_lengths;
  const RowMatrixXd log_b = p.vocal_log_density(z);
  const ViterbiResult vit = viterbi(log_b, pt.startprob, pt.transmat, no_lengths);
  for (double fps : {0.0, 45.0}) {
    CAPTURE(fps);
    const double out = fps == 0 ? 30.0 : fps;
    const TrajectoryEvidence e{out == 30.0 ? yhat : resample_weights(yhat, 30.0, out), 0.7 * prec};
    AnimateOptions o;
    o.fps = fps;
    const RowMatrixXd y = solve_trajectory(p.trajectory_model(fps), resample_states(vit.path, 30.0, out), &e);
    CHECK((p.animate(raw, o).face - y).cwiseAbs().maxCoeff() < 1e-13);
    o.posterior = true;
    const ForwardBackwardResult fb = forward_backward(log_b, pt.startprob, pt.transmat, no_lengths);
    const RowMatrixXd yw =
        solve_trajectory_weighted(p.trajectory_model(fps), resample_weights(fb.posteriors, 30.0, out), &e);
    CHECK((p.animate(raw, o).face - yw).cwiseAbs().maxCoeff() < 1e-13);
    o.guide_weight = 2.0;  // the override replaces the file's λ
    const TrajectoryEvidence e2{e.targets, 2.0 * prec};
    CHECK((p.animate(raw, o).face - solve_trajectory_weighted(p.trajectory_model(fps),
                                                               resample_weights(fb.posteriors, 30.0, out), &e2))
              .cwiseAbs()
              .maxCoeff() < 1e-13);
  }
  // the guide changes the face; animate_states stays unguided
  const Puppet plain(unguided());
  CHECK((p.animate(raw).face - plain.animate(raw).face).cwiseAbs().maxCoeff() > 1e-3);
  const IndexMatrix states = p.animate(raw).states;
  CHECK((p.animate_states(states, 30).face.array() == plain.animate_states(states, 30).face.array()).all());
}

TEST_CASE("guide: λ = 0 (the override or the file's) is the unguided puppet exactly") {
  const Puppet p(guided()), zero(guided(0.0)), plain(unguided());
  const RowMatrixXd raw = audio();
  for (bool posterior : {false, true}) {
    for (double fps : {0.0, 60.0}) {
      AnimateOptions o;
      o.fps = fps;
      o.posterior = posterior;
      const RowMatrixXd ref = plain.animate(raw, o).points;
      CHECK((zero.animate(raw, o).points.array() == ref.array()).all());
      o.guide_weight = 0.0;
      CHECK((p.animate(raw, o).points.array() == ref.array()).all());
      o.guide_weight = std::nan("");  // NaN: the file's λ (1), not unguided
      CHECK((p.animate(raw, o).points - ref).cwiseAbs().maxCoeff() > 1e-3);
    }
  }
  AnimateOptions o;
  o.guide_weight = 1.0;
  CHECK(throws_with<std::invalid_argument>([&] { plain.animate(raw, o); }, "needs a guided puppet"));
  o.guide_weight = INFINITY;
  CHECK(throws_with<std::invalid_argument>([&] { p.animate(raw, o); }, "guide_weight must be finite"));
  CHECK(throws_with<std::invalid_argument>([&] { plain.guide_predict(plain.standardize(raw)); }, "no guide"));
}

TEST_CASE("guide: animate_faces is animate at each weight (one decoding for all)") {
  const Puppet p(guided(0.7)), plain(unguided());
  const RowMatrixXd raw = audio();
  const std::vector<double> weights{0.0, -1.0, 2.0, 16.0};  // −1: the file's λ (0.7)
  for (bool posterior : {false, true}) {
    for (double fps : {0.0, 45.0}) {
      CAPTURE(posterior);
      CAPTURE(fps);
      AnimateOptions o;
      o.fps = fps;
      o.posterior = posterior;
      o.guide_weight = 123.0;  // not used by animate_faces
      const std::vector<RowMatrixXd> faces = p.animate_faces(raw, weights, o);
      REQUIRE(faces.size() == weights.size());
      for (size_t i = 0; i < weights.size(); ++i) {
        o.guide_weight = weights[i];
        CHECK((faces[i].array() == p.animate(raw, o).face.array()).all());
      }
      CHECK((faces[2] - faces[3]).cwiseAbs().maxCoeff() > 1e-3);
      o.guide_weight = 0.0;
      const std::vector<RowMatrixXd> unguided_faces = plain.animate_faces(raw, {0.0, -1.0}, o);
      CHECK((unguided_faces[1].array() == plain.animate(raw, o).face.array()).all());
    }
  }
  CHECK(p.animate_faces(raw, {}).empty());
  CHECK(throws_with<std::invalid_argument>([&] { plain.animate_faces(raw, {0.0, 1.0}); }, "needs a guided puppet"));
  CHECK(throws_with<std::invalid_argument>([&] { p.animate_faces(raw, {1.0, INFINITY}); }, "guide_weight must be finite"));
}

TEST_CASE("guide: given states with their audio are guided as animate; edits change the face where made") {
  const Puppet p(guided(0.7)), plain(unguided());
  const RowMatrixXd raw = audio();
  for (double fps : {0.0, 45.0}) {
    for (double w : {-1.0, 2.0}) {
      CAPTURE(fps);
      CAPTURE(w);
      AnimateOptions o;
      o.fps = fps;
      o.guide_weight = w;
      const AnimateResult ref = p.animate(raw, o);
      const AnimateResult again = p.animate_states(ref.states, 30, raw, o);
      CHECK((again.face.array() == ref.face.array()).all());  // the same solve, bit for bit
      CHECK((again.points.array() == ref.points.array()).all());
      CHECK((again.states.array() == ref.states.array()).all());
      // without the audio the same states are Brand's unguided solve, another face
      CHECK((p.animate_states(ref.states, 30, fps).face - ref.face).cwiseAbs().maxCoeff() > 1e-3);
    }
  }
  const IndexMatrix states = p.animate(raw).states;
  IndexMatrix edited = states;
  edited(3, 0) = 1 - edited(3, 0);
  const RowMatrixXd d = p.animate_states(edited, 30, raw).face - p.animate(raw).face;
  CHECK(d.row(3).cwiseAbs().maxCoeff() > 1e-3);
  CHECK(d.row(3).cwiseAbs().maxCoeff() > 10 * d.row(11).cwiseAbs().maxCoeff());
  // λ = 0, or an unguided puppet: the unguided solve of the states
  AnimateOptions zero;
  zero.guide_weight = 0;
  CHECK((p.animate_states(states, 30, raw, zero).face.array() == p.animate_states(states, 30).face.array()).all());
  CHECK((plain.animate_states(states, 30, raw).face.array() == plain.animate_states(states, 30).face.array()).all());
  // one frame more than the audio (rounding of two rates) is cut; more is refused
  IndexMatrix longer(13, 1);
  longer << states, states.bottomRows(1);
  CHECK((p.animate_states(longer, 30, raw).face.array() == p.animate(raw).face.array()).all());
  const IndexMatrix half = states.topRows(6);
  CHECK(throws_with<std::invalid_argument>([&] { p.animate_states(half, 30, raw); },
                                           "give the audio the states were decoded from"));
  AnimateOptions post;
  post.posterior = true;
  CHECK(throws_with<std::invalid_argument>([&] { p.animate_states(states, 30, raw, post); }, "one path"));
  AnimateOptions ad;
  ad.adapt.kind = AdaptKind::Full;
  CHECK(throws_with<std::invalid_argument>([&] { p.animate_states(states, 30, raw, ad); }, "not decoded"));
  AnimateOptions over;
  over.guide_weight = 1.0;
  CHECK(throws_with<std::invalid_argument>([&] { plain.animate_states(states, 30, raw, over); }, "needs a guided puppet"));
  IndexMatrix bad = states;
  bad(0, 0) = 2;
  CHECK(throws_with<std::invalid_argument>([&] { p.animate_states(bad, 30, raw); }, "[0, 2)"));
}

TEST_CASE("guide: files with and without a guide are written as format version 3 and read") {
  const std::string with = encode_puppet(guided()), without = encode_puppet(unguided());
  CHECK(static_cast<int>(with[8]) == 3);
  CHECK(static_cast<int>(without[8]) == 3);
  const Puppet p(decode_puppet(with)), q(decode_puppet(without));
  CHECK(p.guided());
  CHECK(!q.guided());
  CHECK((p.animate(audio()).face.array() == Puppet(guided()).animate(audio()).face.array()).all());
}

TEST_CASE("guide: bad guide arrays are refused with the array's name") {
  auto refused = [](PuppetFile f, const char* what) {
    CAPTURE(what);
    CHECK(throws_with<std::invalid_argument>([&] { Puppet p(f); }, what));
  };
  PuppetFile f = guided();
  f.arrays.erase("guide/covariance");
  refused(f, "guide/covariance");
  f = guided();
  f.arrays.erase("guide/map");
  refused(f, "no 'guide/map'");
  f = guided();
  f.arrays["guide/context"] = testing::int_arr(101);
  refused(f, "guide/context must be in [0, 100]");
  f = guided();
  f.arrays["guide/columns"] = testing::int_arr(3);
  refused(f, "guide/columns must be in [1, 2]");
  f = guided();
  f.arrays["guide/map"] = testing::arr({3, 1}, {0.5, 1.0, -0.25});  // one column: K = 2 expected
  refused(f, "'guide/map' must be float64 of shape (3, 2)");
  f = guided();
  f.arrays["guide/offset"] = testing::arr({3}, {0, 0, 0});
  refused(f, "guide/offset");
  f = guided();
  f.arrays["guide/weight"] = testing::arr({1}, {-1});
  refused(f, "guide/weight must be >= 0");
  f = guided();
  f.arrays["guide/weight"] = testing::arr({1}, {NAN});
  refused(f, "guide/weight");
  f = guided();
  f.arrays["guide/covariance"] = testing::arr({2, 2}, {0.4, 0.3, 0.1, 0.2});
  refused(f, "guide/covariance is not symmetric");
  f = guided();
  f.arrays["guide/covariance"] = testing::arr({2, 2}, {0.1, 0.4, 0.4, 0.1});
  refused(f, "guide/covariance (rows 0 .. 1) is not positive semi-definite");
  f = guided();
  f.arrays["guide/covariance"] = testing::arr({2, 2}, {-0.1, 0, 0, 0.2});
  refused(f, "guide/covariance (rows 0 .. 1) is not positive semi-definite");
  // a zero covariance (a perfect cross-fitted prediction) is floored absolutely: precision 1e9·I
  f = guided();
  f.arrays["guide/covariance"] = testing::arr({2, 2}, {0, 0, 0, 0});
  const Puppet zero(f);
  CHECK((zero.guide_precision(0) - Eigen::MatrixXd::Identity(2, 2) / kGuideCovarianceFloor).cwiseAbs().maxCoeff() <
        1e-3);
}

TEST_CASE("guide: StreamingPuppet streams a one-part guided puppet as Puppet::animate; λ = 0 as unguided") {
  const Puppet p(guided(0.7)), plain(unguided()), zero(guided(0.0));
  const RowMatrixXd raw = audio();
  for (bool posterior : {false, true}) {
    for (double fps : {0.0, 45.0}) {
      CAPTURE(posterior);
      CAPTURE(fps);
      StreamingOptions o;
      o.decode_lag = 20;  // exact: lags covering the 12 frames (18 at 45 fps)
      o.trajectory_lag = 30;
      o.fps = fps;
      o.posterior = posterior;
      AnimateOptions ao;
      ao.fps = fps;
      ao.posterior = posterior;
      const RowMatrixXd ref = p.animate(raw, ao).face;
      StreamingPuppet s(p, o);
      CHECK(s.options().guide_lag == 1);
      CHECK(s.options().guide_weight == 0.7);
      for (Index chunk : {Index(1), Index(7), Index(12)}) {
        CAPTURE(chunk);
        RowMatrixXd got(0, 2);
        auto take = [&](const StreamedFrames& f) {
          RowMatrixXd both(got.rows() + f.size(), 2);
          both << got, f.face;
          got = both;
        };
        for (Index t = 0; t < raw.rows(); t += chunk) take(s.push(raw.middleRows(t, std::min(chunk, raw.rows() - t))));
        take(s.flush());
        REQUIRE(got.rows() == ref.rows());
        CHECK((got - ref).cwiseAbs().maxCoeff() < 1e-8 * (1.0 + ref.cwiseAbs().maxCoeff()));
      }
      // λ = 0 (the file's or the option) streams Brand's solve, bit for bit the unguided puppet's
      StreamingPuppet a(plain, o), b(zero, o);
      o.guide_weight = 0.0;
      StreamingPuppet c(p, o);
      const RowMatrixXd ya = a.push(raw).face, yb = b.push(raw).face, yc = c.push(raw).face;
      CHECK((ya.array() == yb.array()).all());
      CHECK((ya.array() == yc.array()).all());
      const RowMatrixXd fa = a.flush().face, fb = b.flush().face, fc = c.flush().face;
      CHECK((fa.array() == fb.array()).all());
      CHECK((fa.array() == fc.array()).all());
    }
  }
  StreamingPuppet s(zero);
  CHECK(s.options().delta_lag == 0);
  CHECK(s.options().guide_lag == 0);
}
