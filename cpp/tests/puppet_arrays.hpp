#pragma once
// Puppet file arrays written by hand, for the C++ tests of puppet_io.hpp and puppet.hpp.
#include "voicepuppet/puppet_io.hpp"

#include <cstdint>
#include <utility>
#include <vector>

namespace voicepuppet::testing {

/// A float64 array of the given shape and C-order values.
inline PuppetArray arr(std::vector<std::uint64_t> shape, std::vector<double> v) {
  PuppetArray a;
  a.shape = std::move(shape);
  a.f64 = std::move(v);
  return a;
}

/// A one-element int64 array.
inline PuppetArray int_arr(std::int64_t v) {
  PuppetArray a;
  a.dtype = PuppetArray::DType::Int64;
  a.shape = {1};
  a.i64 = {v};
  return a;
}

// Three points, one part with a 1-D basis moving point 2 vertically, two states, two audio columns.
inline PuppetFile tiny_puppet(double log_scale = 0, double angle = 0, double tx = 0, double ty = 0) {
  PuppetFile f;
  f.metadata = R"({"kind": "test"})";
  f.arrays["fps"] = arr({1}, {30});
  f.arrays["audio/mean"] = arr({2}, {1, -1});
  f.arrays["audio/std"] = arr({2}, {2, 0.5});
  f.arrays["face/mean_shape"] = arr({3, 2}, {-1, 0, 1, 0, 0, 1});
  f.arrays["face/mean_pose"] = arr({4}, {log_scale, angle, tx, ty});
  PuppetArray pts;
  pts.dtype = PuppetArray::DType::Int64;
  pts.shape = {3};
  pts.i64 = {0, 1, 2};
  f.arrays["face/part0/points"] = pts;
  f.arrays["face/part0/basis"] = arr({1, 6}, {0, 0, 0, 0, 0, 1});
  f.arrays["hmm/part0/startprob"] = arr({2}, {1, 0});
  f.arrays["hmm/part0/transmat"] = arr({2, 2}, {0.9, 0.1, 0, 1});
  f.arrays["hmm/part0/face_means"] = arr({2, 2}, {0, 0, 4, 0});
  f.arrays["hmm/part0/face_covars"] = arr({2, 2, 2}, {1, 0.2, 0.2, 0.5, 0.3, 0, 0, 0.1});
  f.arrays["hmm/part0/vocal_means"] = arr({2, 2}, {-1, 0, 1, 0});
  f.arrays["hmm/part0/vocal_covars"] = arr({2, 2}, {0.2, 1, 0.2, 1});
  return f;
}

}  // namespace voicepuppet::testing
