// SPDX-License-Identifier: Apache-2.0
// Tests of io/gif: grey and RGB round trips, loop/delay metadata, argument
// errors, atomic (all-or-nothing) writes and unreadable inputs.
#include "io/gif.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "io/error.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::io {
namespace {

// A 16x16 grey gradient holding every value 0..255 once, shifted per frame so
// the frames differ.
Image8 gradient_frame(int shift) {
  Image8 img;
  img.width = 16;
  img.height = 16;
  img.channels = 1;
  for (int i = 0; i < 256; ++i) img.pixels.push_back(static_cast<std::uint8_t>((i + shift) % 256));
  return img;
}

Image8 grey_frame(int width, int height, std::uint8_t value) {
  Image8 img;
  img.width = width;
  img.height = height;
  img.channels = 1;
  img.pixels.assign(static_cast<std::size_t>(width) * height, value);
  return img;
}

std::string read_bytes(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// The message of the InputError `f` throws ("" and a test failure if none).
template <class F>
std::string input_error_message(F&& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  ADD_FAILURE() << "expected an InputError";
  return "";
}

TEST(Gif, GreyRoundTripIsExact) {
  testing::ScratchDir dir;
  const std::vector<Image8> frames = {gradient_frame(0), gradient_frame(85), gradient_frame(170)};
  write_gif(dir / "grey.gif", frames);
  const std::vector<Image8> back = read_gif(dir / "grey.gif");
  ASSERT_EQ(back.size(), frames.size());
  for (std::size_t i = 0; i < frames.size(); ++i) {
    EXPECT_EQ(back[i].width, 16);
    EXPECT_EQ(back[i].height, 16);
    EXPECT_EQ(back[i].channels, 1);
    EXPECT_EQ(back[i].pixels, frames[i].pixels) << "frame " << i;
  }
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"grey.gif"});  // no temp file left
}

TEST(Gif, InspectReportsFramesSizeDelayAndLooping) {
  testing::ScratchDir dir;
  const std::vector<Image8> frames(4, grey_frame(20, 10, 99));
  write_gif(dir / "a.gif", frames, 70);
  const GifInfo info = inspect_gif(dir / "a.gif");
  EXPECT_EQ(info.width, 20);
  EXPECT_EQ(info.height, 10);
  EXPECT_EQ(info.frames, 4);
  EXPECT_EQ(info.delay_ms, 70);
  EXPECT_TRUE(info.loops);
}

TEST(Gif, DelayIsRoundedToCentisecondsWithTwoMinimum) {
  testing::ScratchDir dir;
  const std::vector<Image8> frames(2, grey_frame(3, 2, 0));
  // {requested ms, stored ms}: nearest centisecond, never below 2 cs.
  for (const auto& [ms, stored] : {std::pair{44, 40}, std::pair{45, 50}, std::pair{0, 20}, std::pair{14, 20},
                                   std::pair{kGifMaxDelayMs, kGifMaxDelayMs}}) {
    write_gif(dir / "d.gif", frames, ms);
    EXPECT_EQ(inspect_gif(dir / "d.gif").delay_ms, stored) << "requested " << ms << " ms";
  }
}

TEST(Gif, RgbRoundTripsWithinPaletteTolerance) {
  testing::ScratchDir dir;
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> byte(0, 255);
  std::vector<Image8> frames(3);
  for (Image8& f : frames) {
    f.width = 24;
    f.height = 11;
    f.channels = 3;
    for (int i = 0; i < 24 * 11 * 3; ++i) f.pixels.push_back(static_cast<std::uint8_t>(byte(rng)));
  }
  write_gif(dir / "rgb.gif", frames);
  const std::vector<Image8> back = read_gif(dir / "rgb.gif");
  ASSERT_EQ(back.size(), frames.size());
  // Nearest-colour quantization: the per-axis nearest cube colour is at most
  // (25, 21, 25) away (level steps 51, 42.5 rounded, 51), and a palette grey is
  // only chosen when nearer still. The bound is attained, so no slack is added.
  const double max_error = std::sqrt(25.0 * 25 + 21.0 * 21 + 25.0 * 25);
  double worst = 0, sum = 0;
  for (std::size_t f = 0; f < frames.size(); ++f) {
    ASSERT_EQ(back[f].channels, 3);
    ASSERT_EQ(back[f].pixels.size(), frames[f].pixels.size());
    for (std::size_t p = 0; p < frames[f].pixels.size(); p += 3) {
      double d2 = 0;
      for (int c = 0; c < 3; ++c) {
        const double d = double(back[f].pixels[p + c]) - frames[f].pixels[p + c];
        d2 += d * d;
      }
      worst = std::max(worst, std::sqrt(d2));
      sum += std::sqrt(d2);
    }
  }
  EXPECT_LE(worst, max_error);
  // Uniform random colours land on average well inside the worst case; a broken
  // palette or index mapping would be off by ~100 or more.
  EXPECT_LT(sum / (frames.size() * 24 * 11), 30.0);
}

TEST(Gif, PaletteColoursAndGreyRampRoundTripExactly) {
  testing::ScratchDir dir;
  // Cube corners/levels (51k, round(42.5k), 51k) and the four extra greys.
  const std::vector<std::uint8_t> colours = {0,   0,   0,   255, 255, 255, 51,  43,  204, 102, 128, 153,
                                             255, 213, 0,   51,  51,  51,  102, 102, 102, 153, 153, 153,
                                             204, 204, 204, 0,   85,  255, 153, 170, 51,  204, 0,   102};
  Image8 img;
  img.width = 12;
  img.height = 1;
  img.channels = 3;
  img.pixels = colours;
  write_gif(dir / "p.gif", std::vector<Image8>{img});
  const std::vector<Image8> back = read_gif(dir / "p.gif");
  ASSERT_EQ(back.size(), 1u);
  EXPECT_EQ(back[0].pixels, colours);
}

TEST(Gif, MismatchedFrameSizesThrowAndLeaveNoFile) {
  testing::ScratchDir dir;
  const std::vector<Image8> frames = {grey_frame(8, 6, 1), grey_frame(8, 6, 2), grey_frame(7, 6, 3)};
  const std::string msg = input_error_message([&] { write_gif(dir / "b.gif", frames); });
  EXPECT_NE(msg.find("b.gif"), std::string::npos) << msg;
  EXPECT_NE(msg.find("frame 2 is 7x6"), std::string::npos) << msg;
  EXPECT_TRUE(dir.entries().empty());
}

TEST(Gif, BadArgumentsThrowNamingTheValue) {
  testing::ScratchDir dir;
  const auto path = dir / "c.gif";
  const std::vector<Image8> ok(1, grey_frame(4, 4, 0));
  EXPECT_NE(input_error_message([&] { write_gif(path, {}); }).find("no frames"), std::string::npos);
  EXPECT_NE(input_error_message([&] { write_gif(path, ok, -1); }).find("-1"), std::string::npos);
  EXPECT_NE(input_error_message([&] { write_gif(path, ok, kGifMaxDelayMs + 1); }).find("655351"), std::string::npos);
  Image8 two_channels = grey_frame(4, 4, 0);
  two_channels.channels = 2;
  two_channels.pixels.resize(32);
  EXPECT_NE(input_error_message([&] { write_gif(path, std::vector<Image8>{two_channels}); }).find("2 channels"),
            std::string::npos);
  const Image8 empty = grey_frame(0, 4, 0);
  EXPECT_NE(input_error_message([&] { write_gif(path, std::vector<Image8>{empty}); }).find("0x4"), std::string::npos);
  Image8 short_buffer = grey_frame(4, 4, 0);
  short_buffer.pixels.pop_back();
  EXPECT_NE(input_error_message([&] { write_gif(path, std::vector<Image8>{short_buffer}); }).find("15"),
            std::string::npos);
  EXPECT_TRUE(dir.entries().empty());
}

TEST(Gif, FailedWriteKeepsExistingFile) {
  testing::ScratchDir dir;
  write_gif(dir / "keep.gif", std::vector<Image8>(2, grey_frame(5, 5, 7)));
  const std::string before = read_bytes(dir / "keep.gif");
  const std::vector<Image8> bad = {grey_frame(5, 5, 1), grey_frame(6, 5, 1)};
  EXPECT_THROW(write_gif(dir / "keep.gif", bad), InputError);
  EXPECT_EQ(read_bytes(dir / "keep.gif"), before);
  EXPECT_EQ(dir.entries().size(), 1u);
}

TEST(Gif, NonGifFileThrowsOnRead) {
  testing::ScratchDir dir;
  testing::write_text(dir / "not.gif", "hello, not a GIF");
  EXPECT_NE(input_error_message([&] { read_gif(dir / "not.gif"); }).find("not.gif"), std::string::npos);
  EXPECT_NE(input_error_message([&] { inspect_gif(dir / "not.gif"); }).find("not.gif"), std::string::npos);
  EXPECT_NE(input_error_message([&] { read_gif(dir / "missing.gif"); }).find("no such file"), std::string::npos);
}

TEST(Gif, TruncatedGifThrowsOnRead) {
  testing::ScratchDir dir;
  std::vector<Image8> frames;
  for (int i = 0; i < 4; ++i) frames.push_back(gradient_frame(i * 31));
  write_gif(dir / "full.gif", frames);
  const std::string bytes = read_bytes(dir / "full.gif");
  testing::write_text(dir / "cut.gif", bytes.substr(0, bytes.size() / 2));
  EXPECT_THROW(read_gif(dir / "cut.gif"), InputError);
}

}  // namespace
}  // namespace hisnegs::io
