// Bindings of the spring-mesh SSD tracker (cpp/include/voicepuppet/tracker.hpp).
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "voicepuppet/tracker.hpp"

namespace py = pybind11;
using namespace voicepuppet;

namespace {

// A GreyImage view of a 2-D uint8 numpy array whose rows are contiguous (any row pitch).
// `keep` receives a C-contiguous copy when the array's columns are not adjacent bytes.
GreyImage grey_from_array(const py::array& a, const char* name, py::array& keep) {
  if (a.ndim() != 2) {
    throw py::value_error(std::string(name) + " must be a 2-D (height, width) uint8 grey image, got " +
                          std::to_string(a.ndim()) + " dimensions; convert colour frames with "
                          "cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)");
  }
  if (!a.dtype().is(py::dtype::of<std::uint8_t>())) {
    throw py::value_error(std::string(name) + " must have dtype uint8, got " +
                          std::string(py::str(a.dtype())) +
                          "; scale to 0..255 and convert with .astype(np.uint8)");
  }
  keep = a;
  if (a.strides(1) != 1 || a.strides(0) < a.shape(1)) {
    keep = py::array_t<std::uint8_t, py::array::c_style | py::array::forcecast>(a);
  }
  GreyImage g;
  g.data = static_cast<const std::uint8_t*>(keep.data());
  g.height = keep.shape(0);
  g.width = keep.shape(1);
  g.stride = keep.strides(0);
  return g;
}

}  // namespace

void bind_tracker(py::module_& m) {
  py::class_<SpringMesh>(m, "SpringMesh", "Springs between trackers: edges, rest lengths, stiffnesses.")
      .def(py::init([](EdgeMatrix edges, VectorXd rest_length, VectorXd stiffness,
                       RowMatrixXd offset_precision, RowMatrixXd offset_mean) {
             SpringMesh s;
             s.edges = std::move(edges);
             s.rest_length = std::move(rest_length);
             s.stiffness = std::move(stiffness);
             s.offset_precision = std::move(offset_precision);
             s.offset_mean = std::move(offset_mean);
             return s;
           }),
           py::arg("edges"), py::arg("rest_length"), py::arg("stiffness"),
           py::arg("offset_precision") = RowMatrixXd(), py::arg("offset_mean") = RowMatrixXd())
      .def_readwrite("edges", &SpringMesh::edges, "#E by 2 point indices")
      .def_readwrite("rest_length", &SpringMesh::rest_length, "#E rest lengths in pixels")
      .def_readwrite("stiffness", &SpringMesh::stiffness, "#E stiffnesses in 1/px^2")
      .def_readwrite("offset_precision", &SpringMesh::offset_precision,
                     "#E by 4 face-frame offset-spring precisions (row-major 2x2), or empty")
      .def_readwrite("offset_mean", &SpringMesh::offset_mean,
                     "#E by 2 face-frame mean offsets of the offset springs, or empty");

  py::class_<TrackerOptions>(m, "TrackerOptions", "Tuning of SpringMeshTracker (see tracker.hpp).")
      .def(py::init<>())
      .def_readwrite("patch_radius", &TrackerOptions::patch_radius)
      .def_readwrite("levels", &TrackerOptions::levels)
      .def_readwrite("max_iterations", &TrackerOptions::max_iterations)
      .def_readwrite("tolerance", &TrackerOptions::tolerance)
      .def_readwrite("intensity_sigma", &TrackerOptions::intensity_sigma)
      .def_readwrite("spring_weight", &TrackerOptions::spring_weight)
      .def_readwrite("ncc_floor", &TrackerOptions::ncc_floor)
      .def_readwrite("ncc_full", &TrackerOptions::ncc_full)
      .def_readwrite("lost_confidence", &TrackerOptions::lost_confidence)
      .def_readwrite("drift_tolerance", &TrackerOptions::drift_tolerance)
      .def_readwrite("damping", &TrackerOptions::damping)
      .def_readwrite("patch_sides", &TrackerOptions::patch_sides)
      .def_readwrite("search_radius", &TrackerOptions::search_radius)
      .def_readwrite("frame_points", &TrackerOptions::frame_points)
      .def_readwrite("search_groups", &TrackerOptions::search_groups)
      .def_readwrite("group_search_radius", &TrackerOptions::group_search_radius)
      .def_readwrite("spring_outlier", &TrackerOptions::spring_outlier)
      .def_readwrite("outlier_edges", &TrackerOptions::outlier_edges)
      .def_readwrite("reference_points", &TrackerOptions::reference_points)
      .def_readwrite("reference_sides", &TrackerOptions::reference_sides)
      .def_readwrite("reference_search_radius", &TrackerOptions::reference_search_radius)
      .def_readwrite("reference_search_ncc", &TrackerOptions::reference_search_ncc)
      .def_readwrite("order_pairs", &TrackerOptions::order_pairs)
      .def_readwrite("order_axis", &TrackerOptions::order_axis)
      .def_readwrite("order_margin", &TrackerOptions::order_margin)
      .def_readwrite("anchor_precision", &TrackerOptions::anchor_precision)
      .def_readwrite("anchor_slack", &TrackerOptions::anchor_slack);

  py::class_<TrackerFrame>(m, "TrackerFrame", "One frame's answer of SpringMeshTracker.track.")
      .def_readonly("points", &TrackerFrame::points, "#P by 2 positions (x, y)")
      .def_readonly("confidence", &TrackerFrame::confidence, "#P confidences in [0, 1]")
      .def_readonly("lost", &TrackerFrame::lost, "#P lost flags")
      .def_readonly("iterations", &TrackerFrame::iterations, "Gauss-Newton iterations spent");

  m.def("delaunay_edges", &delaunay_edges, py::arg("points"),
        "Edges (i < j) of the Delaunay triangulation of #P by 2 points (Bowyer-Watson).");
  m.def("springs_from_points", &springs_from_points, py::arg("points"), py::arg("edges"),
        py::arg("relative_sigma") = 0.05, py::arg("min_sigma") = 0.0,
        "Springs along edges with rest lengths from points and stiffness "
        "1/max(relative_sigma*L, min_sigma)^2.");
  m.def("estimate_springs", &estimate_springs, py::arg("tracks"), py::arg("lost"),
        py::arg("previous"), py::arg("min_sigma") = 0.5, py::arg("frame_points") = VectorXi(),
        "Re-estimate rest lengths (mean) and stiffnesses (1/variance), and the offset springs "
        "(face-frame mean and inverse covariance), from a #T by 2#P pass; with frame_points, "
        "lengths are measured in each frame's face frame.");
  m.def("face_similarity", &face_similarity, py::arg("from"), py::arg("to"), py::arg("idx"),
        "The 2x2 similarity [[a, -b], [b, a]] best mapping centred from[idx] onto to[idx].");

  py::class_<SpringMeshTracker>(m, "SpringMeshTracker",
                                "Spring-mesh SSD tracker: construct on the first frame, then track().")
      .def(py::init([](const py::array& first, const RowMatrixXd& points, const SpringMesh& mesh,
                       const TrackerOptions& options) {
             py::array keep;
             const GreyImage g = grey_from_array(first, "first", keep);
             return SpringMeshTracker(g, points, mesh, options);
           }),
           py::arg("first"), py::arg("points"), py::arg("mesh"),
           py::arg("options") = TrackerOptions())
      .def("track",
           [](SpringMeshTracker& self, const py::array& frame) {
             py::array keep;
             const GreyImage g = grey_from_array(frame, "frame", keep);
             py::gil_scoped_release release;
             return self.track(g);
           },
           py::arg("frame"), "Track the next (height, width) uint8 frame.")
      .def("track",
           [](SpringMeshTracker& self, const py::array& frame, const RowMatrixXd& anchors) {
             py::array keep;
             const GreyImage g = grey_from_array(frame, "frame", keep);
             py::gil_scoped_release release;
             return self.track(g, anchors);
           },
           py::arg("frame"), py::arg("anchors"),
           "Track the next frame with this frame's #P by 2 anchors (NaN rows: none), pulling with "
           "options.anchor_precision.")
      .def("relocate", &SpringMeshTracker::relocate, py::arg("points"),
           "Restart the points at #P by 2 new positions (a face found again elsewhere): current "
           "templates reset to the first-frame ones, per-point state cleared; first-frame "
           "templates and springs kept.")
      .def_property_readonly("points", &SpringMeshTracker::points)
      .def_property_readonly("n_points", &SpringMeshTracker::n_points)
      .def_property_readonly("width", &SpringMeshTracker::width)
      .def_property_readonly("height", &SpringMeshTracker::height)
      .def_property_readonly("levels", &SpringMeshTracker::levels)
      .def_property_readonly("mesh", &SpringMeshTracker::mesh)
      .def_property_readonly("options", &SpringMeshTracker::options);
}
