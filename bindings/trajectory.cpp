// Python bindings of the trajectory kernels (trajectory.hpp). Thin: argument names, the GIL
// released around the solves; the public API with its checks is voicepuppet.trajectory.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>

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
  m.def("solve_trajectory", &solve_trajectory, py::arg("model"), py::arg("states"),
        py::call_guard<py::gil_scoped_release>(), "Most probable trajectory [T,D] for states [T].");
  m.def("solve_trajectory_weighted", &solve_trajectory_weighted, py::arg("model"), py::arg("weights"),
        py::call_guard<py::gil_scoped_release>(), "Posterior-weighted trajectory [T,D] for weights [T,N].");
  m.def("resample_states", &resample_states, py::arg("states"), py::arg("fps_in"), py::arg("fps_out"),
        "Sample-and-hold resampling of a state sequence.");
  m.def("resample_weights", &resample_weights, py::arg("weights"), py::arg("fps_in"), py::arg("fps_out"),
        "Linear-interpolation resampling of per-frame state weights.");
  py::class_<FixedLagTrajectory>(m, "FixedLagTrajectory",
                                 "Streaming synthesis emitting frame t after frame t + lag (trajectory.hpp).")
      .def(py::init<const TrajectoryModel&, Index>(), py::arg("model"), py::arg("lag"))
      .def("push_states", &FixedLagTrajectory::push_states, py::arg("states"),
           py::call_guard<py::gil_scoped_release>())
      .def("push_weights", &FixedLagTrajectory::push_weights, py::arg("weights"),
           py::call_guard<py::gil_scoped_release>())
      .def("flush", &FixedLagTrajectory::flush, py::call_guard<py::gil_scoped_release>())
      .def_property_readonly("lag", &FixedLagTrajectory::lag)
      .def_property_readonly("frames_pushed", &FixedLagTrajectory::frames_pushed)
      .def_property_readonly("frames_emitted", &FixedLagTrajectory::frames_emitted);
}
