#pragma once
/// @file limits.hpp
/// The sane range of every size a user or a file controls: frame rates, frame counts, points,
/// states, dimensions, picture sizes, the nesting of a puppet's metadata. Each is checked where
/// it comes in (a puppet file, an animation, a command-line option), before anything is
/// allocated from it, so a damaged or hostile number is refused with a message instead of
/// exhausting memory or time. Python reads the same table (voicepuppet.limits).

#include "voicepuppet/types.hpp"

#include <string>

namespace voicepuppet {

/// Frame rates (frames per second) of puppets, animations, features and outputs.
constexpr double kMinFps = 1.0;
constexpr double kMaxFps = 1000.0;
/// Frames of one sequence (features, animations, an animation's output): 10^7 is 92 hours at
/// 29.97 fps, 2.8 hours at the largest rate.
constexpr Index kMaxFrames = 10'000'000;
/// Landmarks of a face (a puppet, a landmark file, an animation).
constexpr Index kMaxPoints = 10'000;
/// States of one face part's HMM.
constexpr Index kMaxStates = 1'000;
/// Dimensions of one vector: audio feature columns, vocal features, a part's face coordinates.
constexpr Index kMaxDims = 1'000;
/// Face parts of a puppet.
constexpr Index kMaxParts = 64;
/// Nesting of arrays and objects in a puppet's metadata JSON (Python's json recurses once per
/// level).
constexpr Index kMaxMetadataDepth = 64;
/// Width or height of a rendered picture in pixels.
constexpr Index kMinImageSide = 16;
constexpr Index kMaxImageSide = 8192;
/// |log s| of a puppet's mean pose (s, pixels per unit of the normalised shape, within
/// [e^-14, e^14] ≈ [8e-7, 1.2e6]), and |tx|, |ty|, its translation, in pixels.
constexpr double kMaxLogScale = 14.0;
constexpr double kMaxPixel = 1e6;
/// |value| of a vocal mean, in standard deviations of the training features (or the units of
/// the projection they are a prediction in).
constexpr double kMaxStandardized = 1e6;

/// Throws std::invalid_argument "<what> = <value> is outside [<lo>, <hi>]; <hint>" unless
/// lo <= value <= hi (NaN is outside).
template <class T>
void check_range(const std::string& what, T value, T lo, T hi, const std::string& hint = "") {
  if (!(value >= lo && value <= hi)) {
    fail_argument(what, " = ", value, " is outside [", lo, ", ", hi, "]", hint.empty() ? "" : "; ", hint);
  }
}

/// Throws std::invalid_argument unless `text` is valid UTF-8 (no overlong forms, surrogates or
/// code points above U+10FFFF); `what` names it.
void check_utf8(const std::string& text, const std::string& what);

/// Throws std::invalid_argument if the arrays and objects of the JSON `text` nest deeper than
/// kMaxMetadataDepth (brackets inside strings do not count); `what` names it.
void check_json_depth(const std::string& text, const std::string& what);

}  // namespace voicepuppet
