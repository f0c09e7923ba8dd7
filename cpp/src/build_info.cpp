#include "voicepuppet/types.hpp"

namespace voicepuppet {

BuildInfo build_info() {
  BuildInfo info;
  info.version = VOICEPUPPET_VERSION;
  info.build_type = VOICEPUPPET_BUILD_TYPE;
  info.compiler = VOICEPUPPET_COMPILER;
  info.eigen_version = std::to_string(EIGEN_WORLD_VERSION) + "." +
                       std::to_string(EIGEN_MAJOR_VERSION) + "." +
                       std::to_string(EIGEN_MINOR_VERSION);
  info.simd = Eigen::SimdInstructionSetsInUse();
  return info;
}

}  // namespace voicepuppet
