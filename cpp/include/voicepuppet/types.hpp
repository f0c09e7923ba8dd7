#pragma once
/// @file types.hpp
/// The vocabulary shared by every kernel of libvoicepuppet.
///
/// Matrices are row-major because numpy is: arrays cross the Python boundary without copies.
/// Inputs are taken as `const Eigen::Ref<const RowMatrixXd>&`, results returned by value or in
/// a small named struct. Bad shapes or values throw `std::invalid_argument` (Python sees
/// `ValueError`); numerical failure throws `std::runtime_error`.

#include <Eigen/Core>

#include <cstdint>
#include <sstream>
#include <stdexcept>
#include <string>

namespace voicepuppet {

using Index = std::int64_t;
using RowMatrixXd = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using VectorXd = Eigen::VectorXd;
using VectorXi = Eigen::Matrix<Index, Eigen::Dynamic, 1>;
using MatrixRef = Eigen::Ref<const RowMatrixXd>;
using VectorRef = Eigen::Ref<const VectorXd>;
using IndexVectorRef = Eigen::Ref<const VectorXi>;

/// Throw std::invalid_argument with a message built from the streamed parts, e.g.
/// `fail_argument("log_b must have ", n, " columns (one per state), got ", c)`.
template <class... Parts>
[[noreturn]] void fail_argument(const Parts&... parts) {
  std::ostringstream os;
  (os << ... << parts);
  throw std::invalid_argument(os.str());
}

/// Throw std::runtime_error (a numerical failure) with a message built from the streamed parts.
template <class... Parts>
[[noreturn]] void fail_numeric(const Parts&... parts) {
  std::ostringstream os;
  (os << ... << parts);
  throw std::runtime_error(os.str());
}

/// "rows x cols" of a matrix, for error messages.
template <class M>
std::string shape_of(const M& m) {
  return std::to_string(m.rows()) + " x " + std::to_string(m.cols());
}

/// Throws std::invalid_argument naming `name` if any entry of `m` is NaN or infinite.
template <class M>
void require_finite(const M& m, const char* name) {
  if (!m.allFinite()) {
    fail_argument(name, " contains NaN or infinite values; clean or interpolate them first");
  }
}

/// e^x of every entry, vectorised, and exactly 0 where e^x is below the smallest normal double
/// (x < log DBL_MIN ≈ −708.4). Eigen 3.4's vectorised exp clamps its argument near −709.4, so
/// without this a state of probability e^-1000, or 0 (x = −inf), would come back as ~5.6e−309
/// and keep a count in EM.
template <class Derived>
auto exp_or_zero(const Eigen::ArrayBase<Derived>& x) {
  constexpr double kLogMinNormal = -708.3964185322641;  // log(DBL_MIN)
  return (x < kLogMinNormal).select(0.0, x.exp());
}

/// Library version, build type and compiler, as compiled.
struct BuildInfo {
  std::string version;
  std::string build_type;
  std::string compiler;
  std::string eigen_version;
  std::string simd;
};
BuildInfo build_info();

}  // namespace voicepuppet
