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

}  // namespace voicepuppet::testing
