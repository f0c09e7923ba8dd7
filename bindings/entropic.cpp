// Python bindings of entropic estimation (entropic.hpp). Thin: argument names, defaults, GIL
// released around the heavier kernels; Gaussian statistics arrive as the arrays of an E-step.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "voicepuppet/entropic.hpp"

namespace py = pybind11;
using namespace voicepuppet;

void bind_entropic(py::module_& m) {
  m.def("lambert_w0_log", &lambert_w0_log, py::arg("log_x"), "Principal-branch Lambert W of x = exp(log_x).");
  m.def("lambert_wm1_log", &lambert_wm1_log, py::arg("log_neg_x"),
        "Lower-branch Lambert W₋₁ of x = −exp(log_neg_x), log_neg_x <= −1.");
  m.def("entropic_objective", &entropic_objective, py::arg("omega"), py::arg("theta"), py::arg("z"),
        "Σ_k (ω_k + Z θ_k) log θ_k, the entropic log posterior of a multinomial.");
  m.def("entropic_multinomial", &entropic_multinomial, py::arg("omega"), py::arg("z"),
        "Entropic MAP multinomial θ [K] from evidence ω [K] and prior weight Z.");
  m.def("entropic_rows", &entropic_rows, py::arg("counts"), py::arg("z"), py::arg("old"),
        py::call_guard<py::gil_scoped_release>(),
        "Row-wise entropic MAP estimate of counts [R,K]; rows without evidence kept from old.");
  m.def(
      "entropic_gaussian_mstep",
      [](const VectorRef& weight, const MatrixRef& sum, const MatrixRef& outer, const VectorRef& shift,
         const std::string& type, double z, double prior, const MatrixRef& old_means, const MatrixRef& old_covars) {
        GaussianStats s;
        s.type = parse_covariance_type(type);
        s.weight = weight;
        s.sum = sum;
        s.outer = outer;
        s.shift = shift;
        GaussianParams p;
        {
          py::gil_scoped_release release;
          p = entropic_gaussian_mstep(s, z, prior, old_means, old_covars);
        }
        return py::make_tuple(p.means, p.covars);
      },
      py::arg("weight"), py::arg("sum"), py::arg("outer"), py::arg("shift"), py::arg("covariance_type"),
      py::arg("z"), py::arg("prior"), py::arg("old_means"), py::arg("old_covars"),
      "Entropic MAP (means, covars): K = (S + prior·I) / (w + max(Z, 0)).");
  m.def(
      "entropic_log_prior",
      [](const VectorRef& startprob, const MatrixRef& transmat, const MatrixRef& covars, const std::string& type,
         double z, double prior) {
        return entropic_log_prior(startprob, transmat, covars, parse_covariance_type(type), z, prior);
      },
      py::arg("startprob"), py::arg("transmat"), py::arg("covars"), py::arg("covariance_type"), py::arg("z"),
      py::arg("prior"), "Log entropic prior of a Gaussian HMM (up to a model-independent constant).");
  m.def(
      "entropic_state_costs",
      [](const MatrixRef& transmat, const MatrixRef& covars, const std::string& type, double z, double prior) {
        return entropic_state_costs(transmat, covars, parse_covariance_type(type), z, prior);
      },
      py::arg("transmat"), py::arg("covars"), py::arg("covariance_type"), py::arg("z"), py::arg("prior"),
      "Per-state description cost [N]: −Z Σθ log θ + Z⁺/2 log((2πe)^D|K|) + prior/2 tr K⁻¹.");
  m.def("transition_trim_candidates", &transition_trim_candidates, py::arg("transmat"), py::arg("expected"),
        py::arg("z"), "0/1 flags [N,N] of arcs with θ_ij <= exp(−(ξ_ij/θ_ij)/Z) (never a row's largest).");
  m.def("trim_transitions", &trim_transitions, py::arg("transmat"), py::arg("flags"),
        "transmat with the flagged arcs zeroed and rows renormalised.");
  m.def("anneal_schedule", &anneal_schedule, py::arg("n_iter"), py::arg("z_start"), py::arg("z_final"),
        py::arg("n_anneal"), "Z per iteration: cosine ramp from z_start to z_final over n_anneal iterations.");
}
