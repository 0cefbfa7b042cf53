// SPDX-License-Identifier: Apache-2.0
// Tests of io/png: round trips of grey and RGB images, the display mapping, errors.
#include "io/png.hpp"

#include <gtest/gtest.h>

#include <cmath>

#include "io/error.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::io {
namespace {

TEST(Png, GreyAndRgbRoundTrip) {
  testing::ScratchDir dir;
  for (int channels : {1, 3}) {
    Image8 img;
    img.width = 13;
    img.height = 7;
    img.channels = channels;
    for (int i = 0; i < 13 * 7 * channels; ++i) img.pixels.push_back(static_cast<std::uint8_t>(i * 37));
    write_png(dir / "a.png", img);
    const Image8 back = read_png(dir / "a.png");
    EXPECT_EQ(back.width, 13);
    EXPECT_EQ(back.height, 7);
    EXPECT_EQ(back.channels, channels);
    EXPECT_EQ(back.pixels, img.pixels);
  }
  EXPECT_EQ(dir.entries().size(), 1u);
}

TEST(Png, DisplayMappingSaturates) {
  const std::vector<float> v = {-1.0f, 0.0f, 0.5f, 1.0f, 2.0f, std::nanf("")};
  const Image8 img = to_gray8(v, 6, 1);
  EXPECT_EQ(img.pixels, (std::vector<std::uint8_t>{0, 0, 128, 255, 255, 0}));
}

TEST(Png, BadShapeAndBadFile) {
  testing::ScratchDir dir;
  Image8 img;
  img.width = 4;
  img.height = 4;
  img.channels = 2;
  img.pixels.resize(32);
  EXPECT_THROW(write_png(dir / "x.png", img), InputError);
  EXPECT_TRUE(dir.entries().empty());
  testing::write_text(dir / "not.png", "hello");
  EXPECT_THROW(read_png(dir / "not.png"), InputError);
}

}  // namespace
}  // namespace hisnegs::io
