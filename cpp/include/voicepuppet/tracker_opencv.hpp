#pragma once
/// @file tracker_opencv.hpp
/// Header-only adapter from OpenCV's `cv::Mat` to the tracker's `GreyImage` view, for C++ callers
/// who already use OpenCV. The core library never includes this file and does not need OpenCV:
/// include it after <opencv2/core.hpp> in your own code.
///
///     cv::Mat grey;  cv::cvtColor(frame_bgr, grey, cv::COLOR_BGR2GRAY);
///     auto frame = voicepuppet::grey_view(grey);
///     voicepuppet::TrackerFrame result = tracker.track(frame);

#include "voicepuppet/tracker.hpp"

#include <opencv2/core.hpp>

namespace voicepuppet {

/// A view of an 8-bit single-channel `cv::Mat` (no copy; the Mat must outlive the call that
/// uses the view). Row padding (ROIs, aligned steps) is honoured through the stride.
/// @throws std::invalid_argument when the Mat is empty, not CV_8UC1 or not 2-dimensional:
///         convert with cv::cvtColor(..., cv::COLOR_BGR2GRAY) first.
inline GreyImage grey_view(const cv::Mat& mat) {
  if (mat.empty()) fail_argument("cv::Mat is empty; decode a frame before tracking it");
  if (mat.dims != 2 || mat.type() != CV_8UC1) {
    fail_argument("cv::Mat must be 2-D 8-bit single-channel (CV_8UC1), got type ", mat.type(),
                  " with ", mat.channels(), " channel(s); convert with cv::cvtColor(..., "
                  "cv::COLOR_BGR2GRAY)");
  }
  GreyImage view;
  view.data = mat.ptr<std::uint8_t>(0);
  view.width = mat.cols;
  view.height = mat.rows;
  view.stride = static_cast<Index>(mat.step[0]);
  return view;
}

}  // namespace voicepuppet
