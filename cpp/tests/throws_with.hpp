#pragma once
// The C++ tests' check that an error names what was wrong: whether f throws an E (by default any
// std::exception) whose message contains `needle`.
#include <functional>
#include <stdexcept>
#include <string>

namespace voicepuppet::testing {

template <class E = std::exception>
bool throws_with(const std::function<void()>& f, const std::string& needle) {
  try {
    f();
  } catch (const E& e) {
    return std::string(e.what()).find(needle) != std::string::npos;
  }
  return false;
}

}  // namespace voicepuppet::testing
