// Python bindings of the trajectory kernels (trajectory.hpp). Thin: argument names, the GIL
// released around the solves; the public API with its checks is voicepuppet.trajectory.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <optional>
#include <stdexcept>

#include "voicepuppet/trajectory.hpp"

namespace py = pybind11;
using namespace voicepuppet;

void bind_trajectory(py::module_& m) {
  py::class_<TrajectoryModel>(m, "TrajectoryModel",
                              "Per-state blocks of the trajectory normal equations (trajectory.hpp).")
      .def(py::init([](const MatrixRef& means, const MatrixRef& vel_means, const MatrixRef& covars,
                       const std::string& covariance_type, double velocity_scale) {
             return TrajectoryModel(means, vel_means, covars, parse_covariance_type(covariance_type),
                                    velocity_scale);
           }),
           py::arg("means"), py::arg("vel_means"), py::arg("covars"), py::arg("covariance_type") = "full",
           py::arg("velocity_scale") = 1.0)
      .def_property_readonly("n_states", &TrajectoryModel::n_states)
      .def_property_readonly("n_dims", &TrajectoryModel::n_dims)
      .def_property_readonly("velocity_scale", &TrajectoryModel::velocity_scale)
      .def_property_readonly("covariance_type", [](const TrajectoryModel& t) {
        return t.covariance_type() == CovarianceType::Diagonal ? "diag" : "full";
      });
  // Optional evidence: targets [T,D] and precision W [D,D] (λ folded in), both or neither.
  auto evidence = [](const std::optional<RowMatrixXd>& targets, const std::optional<Eigen::MatrixXd>& precision) {
    if (targets.has_value() != precision.has_value()) {
      throw std::invalid_argument("evidence_targets and evidence_precision go together: pass both or neither");
    }
    std::optional<TrajectoryEvidence> e;
    if (targets) e = TrajectoryEvidence{*targets, *precision};
    return e;
  };
  m.def(
      "solve_trajectory",
      [evidence](const TrajectoryModel& model, const IndexVectorRef& states, const std::optional<RowMatrixXd>& targets,
                 const std::optional<Eigen::MatrixXd>& precision) {
        const auto e = evidence(targets, precision);
        py::gil_scoped_release release;
        return solve_trajectory(model, states, e ? &*e : nullptr);
      },
      py::arg("model"), py::arg("states"), py::arg("evidence_targets") = py::none(),
      py::arg("evidence_precision") = py::none(),
      "Most probable trajectory [T,D] for states [T]; optional per-frame evidence: targets [T,D] with "
      "precision [D,D] (the weight folded in).");
  m.def(
      "solve_trajectory_weighted",
      [evidence](const TrajectoryModel& model, const MatrixRef& weights, const std::optional<RowMatrixXd>& targets,
                 const std::optional<Eigen::MatrixXd>& precision) {
        const auto e = evidence(targets, precision);
        py::gil_scoped_release release;
        return solve_trajectory_weighted(model, weights, e ? &*e : nullptr);
      },
      py::arg("model"), py::arg("weights"), py::arg("evidence_targets") = py::none(),
      py::arg("evidence_precision") = py::none(),
      "Posterior-weighted trajectory [T,D] for weights [T,N]; optional evidence as solve_trajectory.");
  m.def("resample_states", &resample_states, py::arg("states"), py::arg("fps_in"), py::arg("fps_out"),
        "Sample-and-hold resampling of a state sequence.");
  m.def("resample_weights", &resample_weights, py::arg("weights"), py::arg("fps_in"), py::arg("fps_out"),
        "Linear-interpolation resampling of per-frame state weights.");
  py::class_<FixedLagTrajectory>(m, "FixedLagTrajectory",
                                 "Streaming synthesis emitting frame t after frame t + lag (trajectory.hpp).")
      .def(py::init<const TrajectoryModel&, Index>(), py::arg("model"), py::arg("lag"))
      .def(py::init<const TrajectoryModel&, Index, const Eigen::MatrixXd&>(), py::arg("model"), py::arg("lag"),
           py::arg("precision"), "A stream with per-frame evidence of precision W (pushes then take targets).")
      .def("push_states", py::overload_cast<const IndexVectorRef&>(&FixedLagTrajectory::push_states),
           py::arg("states"), py::call_guard<py::gil_scoped_release>())
      .def("push_states",
           py::overload_cast<const IndexVectorRef&, const MatrixRef&>(&FixedLagTrajectory::push_states),
           py::arg("states"), py::arg("targets"), py::call_guard<py::gil_scoped_release>())
      .def("push_weights", py::overload_cast<const MatrixRef&>(&FixedLagTrajectory::push_weights),
           py::arg("weights"), py::call_guard<py::gil_scoped_release>())
      .def("push_weights", py::overload_cast<const MatrixRef&, const MatrixRef&>(&FixedLagTrajectory::push_weights),
           py::arg("weights"), py::arg("targets"), py::call_guard<py::gil_scoped_release>())
      .def("flush", &FixedLagTrajectory::flush, py::call_guard<py::gil_scoped_release>())
      .def_property_readonly("lag", &FixedLagTrajectory::lag)
      .def_property_readonly("has_evidence", &FixedLagTrajectory::has_evidence)
      .def_property_readonly("frames_pushed", &FixedLagTrajectory::frames_pushed)
      .def_property_readonly("frames_emitted", &FixedLagTrajectory::frames_emitted);
}
