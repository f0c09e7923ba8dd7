// Python bindings of the puppet file (puppet_io.hpp) and the C++ puppet (puppet.hpp). Arrays
// cross as numpy arrays (float64 or int64, any number of dimensions); the public API is
// voicepuppet.puppet.model.
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "voicepuppet/limits.hpp"
#include "voicepuppet/puppet.hpp"
#include "voicepuppet/puppet_io.hpp"

namespace py = pybind11;
using namespace voicepuppet;

namespace {

PuppetFile to_file(const std::string& metadata, const py::dict& arrays) {
  PuppetFile f;
  f.metadata = metadata;
  for (auto item : arrays) {
    const std::string name = py::cast<std::string>(item.first);
    py::array raw = py::array::ensure(item.second);
    if (!raw) throw std::invalid_argument("puppet array '" + name + "' is not array-like");
    PuppetArray a;
    const char kind = raw.dtype().kind();
    if (kind == 'i' || kind == 'u' || kind == 'b') {
      auto c = py::array_t<std::int64_t, py::array::c_style | py::array::forcecast>::ensure(raw);
      a.dtype = PuppetArray::DType::Int64;
      a.i64.assign(c.data(), c.data() + c.size());
    } else if (kind == 'f') {
      auto c = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(raw);
      a.f64.assign(c.data(), c.data() + c.size());
    } else {
      throw std::invalid_argument("puppet array '" + name + "' has dtype " +
                                  py::cast<std::string>(py::str(raw.dtype())) +
                                  "; only numbers (float64, int64) are stored: put text in the metadata");
    }
    for (py::ssize_t k = 0; k < raw.ndim(); ++k) a.shape.push_back(static_cast<std::uint64_t>(raw.shape(k)));
    f.arrays.emplace(name, std::move(a));
  }
  return f;
}

py::tuple from_file(const PuppetFile& f) {
  py::dict arrays;
  for (const auto& [name, a] : f.arrays) {
    std::vector<py::ssize_t> shape(a.shape.begin(), a.shape.end());
    if (a.dtype == PuppetArray::DType::Int64) {
      py::array_t<std::int64_t> out(shape);
      std::copy(a.i64.begin(), a.i64.end(), out.mutable_data());
      arrays[py::str(name)] = out;
    } else {
      py::array_t<double> out(shape);
      std::copy(a.f64.begin(), a.f64.end(), out.mutable_data());
      arrays[py::str(name)] = out;
    }
  }
  return py::make_tuple(f.metadata, arrays);
}

py::dict transform_dict(const FeatureTransform& t) {
  py::dict d;
  d["A"] = t.A;
  d["b"] = t.b;
  d["log_likelihood"] = t.log_likelihood;
  return d;
}

py::dict result(const AnimateResult& r) {
  py::dict d;
  d["points"] = r.points;
  d["face"] = r.face;
  d["states"] = r.states;
  d["log_likelihood"] = r.log_likelihood;
  py::list transforms;
  for (const auto& t : r.transforms) transforms.append(transform_dict(t));
  d["transforms"] = transforms;
  return d;
}

AdaptOptions adapt_options(const std::string& kind, double tau, Index n_iter, Index sweeps) {
  AdaptOptions o;
  o.kind = parse_adapt_kind(kind);
  o.tau = tau;
  o.n_iter = n_iter;
  o.sweeps = sweeps;
  return o;
}

}  // namespace

void bind_puppet(py::module_& m) {
  m.attr("PUPPET_FORMAT_VERSION") = kPuppetFormatVersion;
  py::dict limits;  // limits.hpp: (lowest, highest) of each size a user or a file controls
  limits["fps"] = py::make_tuple(kMinFps, kMaxFps);
  limits["frames"] = py::make_tuple(1, kMaxFrames);
  limits["points"] = py::make_tuple(1, kMaxPoints);
  limits["states"] = py::make_tuple(1, kMaxStates);
  limits["dims"] = py::make_tuple(1, kMaxDims);
  limits["parts"] = py::make_tuple(1, kMaxParts);
  limits["metadata_depth"] = py::make_tuple(0, kMaxMetadataDepth);
  limits["image_side"] = py::make_tuple(kMinImageSide, kMaxImageSide);
  limits["pixel"] = py::make_tuple(-kMaxPixel, kMaxPixel);
  m.attr("LIMITS") = limits;
  m.def("crc32", [](const py::bytes& data, std::uint32_t crc) {
          const std::string s = data;
          return crc32(s.data(), s.size(), crc);
        }, py::arg("data"), py::arg("crc") = 0, "CRC-32 as zlib.crc32.");
  m.def("encode_puppet", [](const std::string& metadata, const py::dict& arrays) {
          return py::bytes(encode_puppet(to_file(metadata, arrays)));
        }, py::arg("metadata"), py::arg("arrays"), "Puppet container bytes from JSON text and arrays.");
  m.def("decode_puppet", [](const py::bytes& data, const std::string& source) {
          return from_file(decode_puppet(std::string(data), source));
        }, py::arg("data"), py::arg("source") = "puppet data", "(metadata, arrays) from container bytes.");
  m.def("write_puppet_file", [](const std::string& path, const std::string& metadata, const py::dict& arrays) {
          PuppetFile f = to_file(metadata, arrays);
          py::gil_scoped_release release;
          write_puppet_file(path, f);
        }, py::arg("path"), py::arg("metadata"), py::arg("arrays"), "Write a puppet file atomically.");
  m.def("read_puppet_file", [](const std::string& path) { return from_file(read_puppet_file(path)); },
        py::arg("path"), "(metadata, arrays) of a puppet file, validated.");

  m.def("adapt_features",
        [](const MatrixRef& z, const IndexVectorRef& lengths, const MatrixRef& means, const MatrixRef& covars,
           const std::string& covariance_type, const VectorRef& startprob, const MatrixRef& transmat,
           const std::string& kind, double tau, Index n_iter, Index sweeps) {
          const AdaptOptions o = adapt_options(kind, tau, n_iter, sweeps);
          const CovarianceType ct = parse_covariance_type(covariance_type);
          FeatureTransform t;
          {
            py::gil_scoped_release release;
            t = adapt_features(z, lengths, means, covars, ct, startprob, transmat, o);
          }
          return transform_dict(t);
        },
        py::arg("z"), py::arg("lengths"), py::arg("means"), py::arg("covars"), py::arg("covariance_type"),
        py::arg("startprob"), py::arg("transmat"), py::arg("kind"), py::arg("tau") = AdaptOptions{}.tau,
        py::arg("n_iter") = AdaptOptions{}.n_iter, py::arg("sweeps") = AdaptOptions{}.sweeps,
        "Test-time adaptation of features z [T, D] to a Gaussian HMM (adapt.hpp): {A, b, log_likelihood}.");
  m.def("append_deltas", &append_deltas, py::arg("x"), py::arg("width"),
        "[x, regression deltas over +-width frames] (puppet.hpp).");
  py::class_<Puppet>(m, "Puppet", "The C++ voice puppet (puppet.hpp).")
      .def(py::init([](const std::string& metadata, const py::dict& arrays) {
             return Puppet(to_file(metadata, arrays));
           }), py::arg("metadata"), py::arg("arrays"))
      .def_static("load", &Puppet::load, py::arg("path"))
      .def_property_readonly("fps", &Puppet::fps)
      .def_property_readonly("n_features", &Puppet::n_features)
      .def_property_readonly("n_points", &Puppet::n_points)
      .def_property_readonly("n_parts", &Puppet::n_parts)
      .def_property_readonly("n_dims", &Puppet::n_dims)
      .def_property_readonly("delta_width", &Puppet::delta_width)
      .def_property_readonly("metadata", [](const Puppet& p) { return p.file().metadata; })
      .def("n_states", [](const Puppet& p, Index part) { return p.part(part).n_states(); }, py::arg("part") = 0)
      .def("startprob", [](const Puppet& p, Index part) { return p.part(part).startprob; }, py::arg("part") = 0)
      .def("transmat", [](const Puppet& p, Index part) { return p.part(part).transmat; }, py::arg("part") = 0)
      .def("standardize", &Puppet::standardize, py::arg("raw"))
      .def_property_readonly("projected", &Puppet::projected)
      .def_property_readonly("projection_context", &Puppet::projection_context)
      .def_property_readonly("n_vocal", &Puppet::n_vocal)
      .def_property_readonly("vocal_delta_width", &Puppet::vocal_delta_width)
      .def("project", &Puppet::project, py::arg("standardized"))
      .def_property_readonly("guided", &Puppet::guided)
      .def_property_readonly("guide_context", &Puppet::guide_context)
      .def_property_readonly("guide_columns", &Puppet::guide_columns)
      .def_property_readonly("guide_map", &Puppet::guide_map)
      .def_property_readonly("guide_offset", &Puppet::guide_offset)
      .def_property_readonly("guide_weight", &Puppet::guide_weight)
      .def_property_readonly("guide_covariance", &Puppet::guide_covariance)
      .def("guide_precision", &Puppet::guide_precision, py::arg("part") = 0)
      .def("guide_predict", &Puppet::guide_predict, py::arg("standardized"))
      .def("vocal_log_density", &Puppet::vocal_log_density, py::arg("standardized"), py::arg("part") = 0,
           py::call_guard<py::gil_scoped_release>())
      .def("trajectory_model", &Puppet::trajectory_model, py::arg("out_fps") = 0.0, py::arg("part") = 0)
      .def("to_points", &Puppet::to_points, py::arg("face"))
      .def("animate", [](const Puppet& p, const MatrixRef& raw, double fps, bool posterior,
                         const std::string& adapt, double tau, Index n_iter, double guide_weight) {
             AnimateOptions o;
             o.fps = fps;
             o.posterior = posterior;
             o.guide_weight = guide_weight;
             o.adapt = adapt_options(adapt, tau, n_iter, AdaptOptions{}.sweeps);
             AnimateResult r;
             {
               py::gil_scoped_release release;
               r = p.animate(raw, o);
             }
             return result(r);
           }, py::arg("raw_features"), py::arg("fps") = 0.0, py::arg("posterior") = false,
           py::arg("adapt") = "none", py::arg("tau") = AdaptOptions{}.tau,
           py::arg("n_iter") = AdaptOptions{}.n_iter, py::arg("guide_weight") = AnimateOptions{}.guide_weight)
      .def("animate_faces", [](const Puppet& p, const MatrixRef& raw, const std::vector<double>& guide_weights,
                               double fps, bool posterior) {
             AnimateOptions o;
             o.fps = fps;
             o.posterior = posterior;
             py::gil_scoped_release release;
             return p.animate_faces(raw, guide_weights, o);
           }, py::arg("raw_features"), py::arg("guide_weights"), py::arg("fps") = 0.0, py::arg("posterior") = false,
           "The face coordinates of animate(raw_features, fps, posterior, guide_weight=w) for each w of\n"
           "guide_weights: the audio decoded once, the trajectory solved once per weight.")
      .def("animate_states", [](const Puppet& p, const Eigen::Ref<const IndexMatrix>& states, double states_fps,
                                double fps) {
             AnimateResult r;
             {
               py::gil_scoped_release release;
               r = p.animate_states(states, states_fps, fps);
             }
             return result(r);
           }, py::arg("states"), py::arg("states_fps"), py::arg("fps") = 0.0)
      .def("animate_states_guided", [](const Puppet& p, const Eigen::Ref<const IndexMatrix>& states,
                                       double states_fps, const MatrixRef& raw, double fps, double guide_weight) {
             AnimateOptions o;
             o.fps = fps;
             o.guide_weight = guide_weight;
             AnimateResult r;
             {
               py::gil_scoped_release release;
               r = p.animate_states(states, states_fps, raw, o);
             }
             return result(r);
           }, py::arg("states"), py::arg("states_fps"), py::arg("raw_features"), py::arg("fps") = 0.0,
           py::arg("guide_weight") = AnimateOptions{}.guide_weight,
           "animate_states with the guide's evidence from the audio the states go with (raw feature\n"
           "frames at the puppet's rate): unedited states give animate(raw_features) exactly.");
}
