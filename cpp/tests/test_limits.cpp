// Tests of limits.hpp: ranges named with the value and the bounds, UTF-8 and JSON nesting checks.
#include <doctest/doctest.h>

#include "throws_with.hpp"

#include "voicepuppet/limits.hpp"

#include <stdexcept>
#include <string>

using namespace voicepuppet;
using voicepuppet::testing::throws_with;

TEST_CASE("check_range names the field, the value and the range, and refuses NaN") {
  check_range("fps", 30.0, kMinFps, kMaxFps);
  check_range("fps", kMaxFps, kMinFps, kMaxFps);
  CHECK(throws_with<std::invalid_argument>([] { check_range("puppet fps", 1e9, kMinFps, kMaxFps, "retrain"); },
                                           "puppet fps = 1e+09 is outside [1, 1000]; retrain"));
  CHECK(throws_with<std::invalid_argument>([] { check_range("fps", std::nan(""), kMinFps, kMaxFps); }, "fps = nan"));
  CHECK(throws_with<std::invalid_argument>([] { check_range<Index>("frames", kMaxFrames + 1, 1, kMaxFrames); },
                                           "frames = 10000001 is outside [1, 10000000]"));
}

TEST_CASE("check_utf8 accepts UTF-8 and refuses stray, truncated, overlong and surrogate bytes") {
  check_utf8("", "t");
  check_utf8("plain \xc3\xa9t\xc3\xa9 \xe2\x82\xac \xf0\x9f\x98\x80", "t");  // é, €, an emoji
  for (const std::string bad : {"\xff", "a\xc3", "\xc0\xaf", "\xe0\x80\xaf", "\xed\xa0\x80", "\xf4\x90\x80\x80",
                                "\x80", "\xe2\x82"}) {
    CAPTURE(bad);
    CHECK(throws_with<std::invalid_argument>([&] { check_utf8(bad, "the metadata"); },
                                             "the metadata is not valid UTF-8"));
  }
}

TEST_CASE("check_json_depth counts brackets outside strings only") {
  const std::string ok = std::string(kMaxMetadataDepth, '[') + std::string(kMaxMetadataDepth, ']');
  check_json_depth(ok, "m");
  check_json_depth(R"({"a": "[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[\"[[["})", "m");
  const std::string deep = "[" + ok + "]";
  CHECK(throws_with<std::invalid_argument>([&] { check_json_depth(deep, "m"); }, "m nests arrays and objects deeper than 64"));
  const std::string objects = std::string(100000, '{');
  CHECK(throws_with<std::invalid_argument>([&] { check_json_depth(objects, "m"); }, "deeper than 64"));
}
