// Python bindings of the HMM kernels (hmm.hpp, hmm_gaussian.hpp). Thin: argument names and
// defaults, GIL released around the kernels, results reshaped into tuples/dicts of arrays.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "voicepuppet/hmm.hpp"
#include "voicepuppet/hmm_gaussian.hpp"

namespace py = pybind11;
using namespace voicepuppet;

namespace {

py::dict stats_to_dict(const EStepResult& r) {
  py::dict d;
  d["log_likelihood"] = r.log_likelihood;
  d["expected_transitions"] = r.expected_transitions;
  d["expected_starts"] = r.expected_starts;
  d["weight"] = r.stats.weight;
  d["sum"] = r.stats.sum;
  d["outer"] = r.stats.outer;
  d["shift"] = r.stats.shift;
  return d;
}

py::dict info_to_dict(const ScreeningInfo& info) {
  py::dict d;
  d["entries"] = info.entries;
  d["refined"] = info.refined;
  d["rounds"] = info.rounds;
  d["all_double"] = info.all_double;
  return d;
}

py::tuple fb_to_tuple(const ForwardBackwardResult& r) {
  return py::make_tuple(r.log_likelihood, r.posteriors, r.expected_transitions, r.expected_starts,
                        r.sequence_log_likelihoods);
}

}  // namespace

void bind_hmm(py::module_& m) {
  m.def(
      "forward_backward",
      [](const MatrixRef& log_b, const VectorRef& startprob, const MatrixRef& transmat,
         const IndexVectorRef& lengths, const std::string& implementation) {
        ForwardBackwardResult r;
        {
          py::gil_scoped_release release;
          if (implementation == "scaled") {
            r = forward_backward(log_b, startprob, transmat, lengths);
          } else if (implementation == "log") {
            r = forward_backward_log(log_b, startprob, transmat, lengths);
          } else {
            fail_argument("implementation must be 'scaled' or 'log', got '", implementation, "'");
          }
        }
        return fb_to_tuple(r);
      },
      py::arg("log_b"), py::arg("startprob"), py::arg("transmat"), py::arg("lengths"),
      py::arg("implementation") = "scaled",
      "Forward-backward on log emissions log_b [T,N]. Returns (log_likelihood, posteriors [T,N], "
      "expected_transitions [N,N], expected_starts [N], sequence_log_likelihoods [S]). "
      "implementation='scaled' (the name kept for callers) is the fast pass on log lattices with "
      "shifted linear sums, exact in every regime; 'log' is the log-sum-exp reference.");
  m.def("forward_lattice_log", &forward_lattice_log, py::arg("log_b"), py::arg("startprob"),
        py::arg("transmat"), py::call_guard<py::gil_scoped_release>(),
        "log α [T,N] of one sequence.");
  m.def("backward_lattice_log", &backward_lattice_log, py::arg("log_b"), py::arg("transmat"),
        py::call_guard<py::gil_scoped_release>(), "log β [T,N] of one sequence.");
  m.def("log_likelihood", &log_likelihood, py::arg("log_b"), py::arg("startprob"), py::arg("transmat"),
        py::arg("lengths"), py::call_guard<py::gil_scoped_release>(),
        "Total log-likelihood of the sequences (forward pass only).");
  m.def(
      "viterbi",
      [](const MatrixRef& log_b, const VectorRef& startprob, const MatrixRef& transmat,
         const IndexVectorRef& lengths) {
        ViterbiResult r;
        {
          py::gil_scoped_release release;
          r = viterbi(log_b, startprob, transmat, lengths);
        }
        return py::make_tuple(r.log_probability, r.path);
      },
      py::arg("log_b"), py::arg("startprob"), py::arg("transmat"), py::arg("lengths"),
      "Viterbi decoding. Returns (log_probability, path [T]).");
  m.def(
      "gaussian_log_density",
      [](const MatrixRef& X, const MatrixRef& means, const MatrixRef& covars, const std::string& type) {
        const CovarianceType ct = parse_covariance_type(type);
        py::gil_scoped_release release;
        return gaussian_log_density(X, means, covars, ct);
      },
      py::arg("X"), py::arg("means"), py::arg("covars"), py::arg("covariance_type"),
      "log N(x_t; μ_n, Σ_n) [T,N]; full covars stacked as [N*D, D], diag as [N, D].");
  m.def(
      "check_covariances",
      [](const MatrixRef& covars, Index n_states, Index n_dims, const std::string& type) {
        check_covariances(covars, n_states, n_dims, parse_covariance_type(type));
      },
      py::arg("covars"), py::arg("n_states"), py::arg("n_dims"), py::arg("covariance_type"));
  m.def(
      "gaussian_log_density_screened",
      [](const MatrixRef& X, const MatrixRef& means, const MatrixRef& covars) {
        ScreenedLogDensity r;
        {
          py::gil_scoped_release release;
          r = gaussian_log_density_screened(X, means, covars);
        }
        return py::make_tuple(r.log_b, r.bound);
      },
      py::arg("X"), py::arg("means"), py::arg("covars"),
      "Full-covariance log densities evaluated in float32, and bounds on their error: "
      "(log_b [T,N], bound [T,N]); bound is inf where float32 overflowed.");
  m.def(
      "gaussian_hmm_score",
      [](const MatrixRef& X, const IndexVectorRef& lengths, const VectorRef& startprob, const MatrixRef& transmat,
         const MatrixRef& means, const MatrixRef& covars, const std::string& type, bool exact) {
        const CovarianceType ct = parse_covariance_type(type);
        ScreeningInfo info;
        double ll = 0;
        {
          py::gil_scoped_release release;
          ll = gaussian_hmm_score(X, lengths, startprob, transmat, means, covars, ct, exact, &info);
        }
        return py::make_tuple(ll, info_to_dict(info));
      },
      py::arg("X"), py::arg("lengths"), py::arg("startprob"), py::arg("transmat"), py::arg("means"),
      py::arg("covars"), py::arg("covariance_type"), py::arg("exact") = false,
      "log p(X) of a Gaussian HMM from the data; full covariances are screened in float32 and "
      "refined in double unless exact. Returns (log_likelihood, screening info dict).");
  m.def(
      "gaussian_hmm_decode",
      [](const MatrixRef& X, const IndexVectorRef& lengths, const VectorRef& startprob, const MatrixRef& transmat,
         const MatrixRef& means, const MatrixRef& covars, const std::string& type, bool exact) {
        const CovarianceType ct = parse_covariance_type(type);
        ScreeningInfo info;
        ViterbiResult r;
        {
          py::gil_scoped_release release;
          r = gaussian_hmm_decode(X, lengths, startprob, transmat, means, covars, ct, exact, &info);
        }
        return py::make_tuple(r.log_probability, r.path, info_to_dict(info));
      },
      py::arg("X"), py::arg("lengths"), py::arg("startprob"), py::arg("transmat"), py::arg("means"),
      py::arg("covars"), py::arg("covariance_type"), py::arg("exact") = false,
      "Viterbi decoding of a Gaussian HMM from the data (screened unless exact). Returns "
      "(log_probability, path [T], screening info dict).");
  m.def(
      "gaussian_hmm_posteriors",
      [](const MatrixRef& X, const IndexVectorRef& lengths, const VectorRef& startprob, const MatrixRef& transmat,
         const MatrixRef& means, const MatrixRef& covars, const std::string& type, bool exact) {
        const CovarianceType ct = parse_covariance_type(type);
        ScreeningInfo info;
        ForwardBackwardResult r;
        {
          py::gil_scoped_release release;
          r = gaussian_hmm_posteriors(X, lengths, startprob, transmat, means, covars, ct, exact, &info);
        }
        return py::make_tuple(r.log_likelihood, r.posteriors, r.expected_transitions, r.expected_starts,
                              r.sequence_log_likelihoods, info_to_dict(info));
      },
      py::arg("X"), py::arg("lengths"), py::arg("startprob"), py::arg("transmat"), py::arg("means"),
      py::arg("covars"), py::arg("covariance_type"), py::arg("exact") = false,
      "Forward-backward of a Gaussian HMM from the data (screened unless exact). Returns "
      "(log_likelihood, posteriors [T,N], expected_transitions [N,N], expected_starts [N], "
      "sequence_log_likelihoods [S], screening info dict).");
  m.def(
      "gaussian_hmm_estep",
      [](const MatrixRef& X, const IndexVectorRef& lengths, const VectorRef& startprob,
         const MatrixRef& transmat, const MatrixRef& means, const MatrixRef& covars, const std::string& type,
         const VectorRef& shift, bool exact) {
        const CovarianceType ct = parse_covariance_type(type);
        EStepResult r;
        ScreeningInfo info;
        {
          py::gil_scoped_release release;
          r = gaussian_hmm_estep(X, lengths, startprob, transmat, means, covars, ct, shift, exact, &info);
        }
        py::dict d = stats_to_dict(r);
        d["screening"] = info_to_dict(info);
        return d;
      },
      py::arg("X"), py::arg("lengths"), py::arg("startprob"), py::arg("transmat"), py::arg("means"),
      py::arg("covars"), py::arg("covariance_type"), py::arg("shift"), py::arg("exact") = false,
      "E-step: dict of log_likelihood, expected_transitions, expected_starts and the Gaussian "
      "statistics weight [N], sum [N,D], outer (full [N*D,D], diag [N,D]) about shift [D], and "
      "screening (what the float32 screening did; exact=True evaluates every density in double).");
  m.def(
      "gaussian_stats",
      [](const MatrixRef& X, const MatrixRef& posteriors, const VectorRef& shift, const std::string& type) {
        const CovarianceType ct = parse_covariance_type(type);
        GaussianStats s;
        {
          py::gil_scoped_release release;
          s = gaussian_stats(X, posteriors, shift, ct);
        }
        return py::make_tuple(s.weight, s.sum, s.outer);
      },
      py::arg("X"), py::arg("posteriors"), py::arg("shift"), py::arg("covariance_type"),
      "Posterior-weighted statistics (weight [N], sum [N,D], outer) of X about shift.");
  m.def(
      "gaussian_mstep",
      [](const VectorRef& weight, const MatrixRef& sum, const MatrixRef& outer, const VectorRef& shift,
         const std::string& type, double variance_floor, const MatrixRef& old_means,
         const MatrixRef& old_covars) {
        GaussianStats s;
        s.type = parse_covariance_type(type);
        s.weight = weight;
        s.sum = sum;
        s.outer = outer;
        s.shift = shift;
        GaussianParams p;
        {
          py::gil_scoped_release release;
          p = gaussian_mstep(s, variance_floor, old_means, old_covars);
        }
        return py::make_tuple(p.means, p.covars);
      },
      py::arg("weight"), py::arg("sum"), py::arg("outer"), py::arg("shift"), py::arg("covariance_type"),
      py::arg("variance_floor"), py::arg("old_means"), py::arg("old_covars"),
      "Maximum-likelihood (means, covars) from statistics; variance_floor added to the diagonals.");
  m.def("normalize_counts", &normalize_counts, py::arg("counts"), py::arg("old"),
        "Row-normalised counts; rows without evidence are taken from old.");
  m.def("kmeans", &kmeans, py::arg("X"), py::arg("k"), py::arg("seed"), py::arg("n_iter") = 30,
        py::call_guard<py::gil_scoped_release>(), "k-means++ seeding and Lloyd iterations: centres [k,D].");
  m.def(
      "gaussian_hmm_sample",
      [](const VectorRef& startprob, const MatrixRef& transmat, const MatrixRef& means, const MatrixRef& covars,
         const std::string& type, Index n_frames, std::uint64_t seed) {
        const CovarianceType ct = parse_covariance_type(type);
        SampleResult r;
        {
          py::gil_scoped_release release;
          r = gaussian_hmm_sample(startprob, transmat, means, covars, ct, n_frames, seed);
        }
        return py::make_tuple(r.X, r.states);
      },
      py::arg("startprob"), py::arg("transmat"), py::arg("means"), py::arg("covars"),
      py::arg("covariance_type"), py::arg("n_frames"), py::arg("seed"),
      "Sample (X [T,D], states [T]) from a Gaussian HMM.");
}
