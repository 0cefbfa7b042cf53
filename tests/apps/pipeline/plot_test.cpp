// SPDX-License-Identifier: Apache-2.0
// Tests of apps/pipeline/plot: image shape, where lines land (linear and log axes), broken
// lines, empty plots, text, legend, palette, tick labels and option errors.
#include "apps/pipeline/plot.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "io/error.hpp"

namespace hisnegs::apps {
namespace {

using Rgb = std::array<std::uint8_t, 3>;
// Not in the palette and far from black, white and the grid grey.
constexpr Rgb kRed{200, 30, 40};
constexpr double kNan = std::numeric_limits<double>::quiet_NaN();

Rgb pixel(const io::Image8& img, int x, int y) {
  const std::uint8_t* p = &img.pixels[(static_cast<std::size_t>(y) * img.width + x) * 3];
  return {p[0], p[1], p[2]};
}

struct Pixel {
  int x, y;
};

std::vector<Pixel> pixels_of(const io::Image8& img, const Rgb& c) {
  std::vector<Pixel> out;
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x)
      if (pixel(img, x, y) == c) out.push_back({x, y});
  return out;
}

bool is_black(const io::Image8& img, int x, int y) { return pixel(img, x, y) == Rgb{0, 0, 0}; }

// The axes box: outermost rows/columns that are mostly black (text never is).
struct Box {
  int left = -1, top = -1, right = -1, bottom = -1;
};
Box find_box(const io::Image8& img) {
  Box b;
  for (int y = 0; y < img.height; ++y) {
    int n = 0;
    for (int x = 0; x < img.width; ++x) n += is_black(img, x, y);
    if (n > img.width / 2) (b.top < 0 ? b.top : b.bottom) = y;
  }
  for (int x = 0; x < img.width; ++x) {
    int n = 0;
    for (int y = 0; y < img.height; ++y) n += is_black(img, x, y);
    if (n > img.height / 2) (b.left < 0 ? b.left : b.right) = x;
  }
  return b;
}

// Rows that are mostly light grey: the grid lines of the labelled y ticks.
int grid_rows(const io::Image8& img) {
  int rows = 0;
  for (int y = 0; y < img.height; ++y) {
    int n = 0;
    for (int x = 0; x < img.width; ++x) {
      const Rgb c = pixel(img, x, y);
      n += c[0] == c[1] && c[1] == c[2] && c[0] >= 200 && c[0] < 255;
    }
    rows += n > img.width / 2;
  }
  return rows;
}

PlotSeries line(std::vector<double> x, std::vector<double> y, std::string label = "") {
  return PlotSeries{std::move(label), std::move(x), std::move(y), kRed};
}

// Mean row of the series' pixels in column `x` (NaN if none).
double mean_row(const std::vector<Pixel>& px, int x) {
  double sum = 0;
  int n = 0;
  for (const Pixel& p : px)
    if (p.x == x) sum += p.y, ++n;
  return n ? sum / n : kNan;
}

int min_x(const std::vector<Pixel>& px) {
  int m = 1 << 30;
  for (const Pixel& p : px) m = std::min(m, p.x);
  return m;
}
int max_x(const std::vector<Pixel>& px) {
  int m = -1;
  for (const Pixel& p : px) m = std::max(m, p.x);
  return m;
}

TEST(Plot, ImageHasRequestedSizeAndThreeChannels) {
  const std::vector<PlotSeries> s = {line({0, 1}, {0, 1})};
  PlotOptions o;
  o.width = 321;
  o.height = 203;
  const io::Image8 img = plot_lines(s, o);
  EXPECT_EQ(img.width, 321);
  EXPECT_EQ(img.height, 203);
  EXPECT_EQ(img.channels, 3);
  EXPECT_EQ(img.pixels.size(), 321u * 203u * 3u);
  EXPECT_EQ(pixel(img, 0, 0), (Rgb{255, 255, 255}));  // white background
}

TEST(Plot, RisingLineGoesUpToTheRightInsideTheBox) {
  const std::vector<PlotSeries> s = {line({0, 2, 4, 6, 8, 10}, {0, 2, 4, 6, 8, 10})};
  const io::Image8 img = plot_lines(s, PlotOptions{});
  const std::vector<Pixel> px = pixels_of(img, kRed);
  ASSERT_GT(px.size(), 500u);
  const Box box = find_box(img);
  for (const Pixel& p : px) {
    ASSERT_GT(p.x, box.left);
    ASSERT_LT(p.x, box.right);
    ASSERT_GT(p.y, box.top);
    ASSERT_LT(p.y, box.bottom);
  }
  // Greater x -> smaller row, all along the line.
  const int x0 = min_x(px), x1 = max_x(px);
  EXPECT_GT(x1 - x0, img.width / 2);
  double previous = 1e9;
  for (int x = x0 + 2; x <= x1 - 2; x += 20) {
    const double row = mean_row(px, x);
    ASSERT_FALSE(std::isnan(row)) << "gap at column " << x;
    EXPECT_LT(row, previous) << "column " << x;
    previous = row;
  }
}

TEST(Plot, LogYPlacesDecadesEvenly) {
  // y = 10^x is straight on a log axis: the middle column's row is the mean of the
  // end rows. On a linear axis the middle (y ~ 32 of 1000) lies near the bottom.
  const std::vector<PlotSeries> s = {line({0, 1, 2, 3}, {1, 10, 100, 1000})};
  for (const bool log : {true, false}) {
    PlotOptions o;
    o.log_y = log;
    const std::vector<Pixel> px = pixels_of(plot_lines(s, o), kRed);
    const int x0 = min_x(px) + 3, x1 = max_x(px) - 3;
    const double straight = 0.5 * (mean_row(px, x0) + mean_row(px, x1));
    const double middle = mean_row(px, (x0 + x1) / 2);
    if (log)
      EXPECT_NEAR(middle, straight, 3.0);
    else
      EXPECT_GT(middle - straight, 100.0);
  }
}

TEST(Plot, SmallLinearRangeGetsSeveralTicks) {
  // +-0.004: a step rounded up to 0.005 would leave only the tick at 0.
  std::vector<double> x, y;
  for (int i = 0; i <= 100; ++i) x.push_back(0.06 * i), y.push_back(0.0043 * std::sin(0.06 * i));
  EXPECT_GE(grid_rows(plot_lines(std::vector<PlotSeries>{line(x, y)}, PlotOptions{})), 3);
}

TEST(Plot, NarrowLogRangeLabelsTwoAndFive) {
  // Data 2..8 spans no whole decade: the axis widens to 1..10, and 2 and 5 get
  // ticks with grid lines so there is something to read between 1 and 10.
  PlotOptions o;
  o.log_y = true;
  const std::vector<PlotSeries> s = {line({0, 1, 2, 3}, {2, 3, 5, 8})};
  EXPECT_GE(grid_rows(plot_lines(s, o)), 3);
}

TEST(Plot, LogAxisSkipsNonPositivePoints) {
  PlotOptions o;
  o.log_y = true;
  const std::vector<PlotSeries> with = {line({0, 1, 2, 3, 4}, {0, -5, 1, 10, 100})};
  const std::vector<PlotSeries> without = {line({2, 3, 4}, {1, 10, 100})};
  const io::Image8 a = plot_lines(with, o), b = plot_lines(without, o);
  EXPECT_FALSE(pixels_of(a, kRed).empty());
  EXPECT_EQ(a.pixels, b.pixels);
}

TEST(Plot, LogAxisWithNoPositiveValueDrawsEmptyAxes) {
  PlotOptions o;
  o.log_y = true;
  const std::vector<PlotSeries> s = {line({0, 1, 2}, {0, -1, -2})};
  const io::Image8 img = plot_lines(s, o);
  EXPECT_TRUE(pixels_of(img, kRed).empty());
  EXPECT_GE(find_box(img).right, 0);
}

TEST(Plot, NonFinitePointsBreakTheLine) {
  std::vector<double> x, y;
  for (int i = 0; i <= 10; ++i) x.push_back(i), y.push_back(i);
  y[5] = kNan;
  const std::vector<Pixel> px = pixels_of(plot_lines(std::vector<PlotSeries>{line(x, y)}, PlotOptions{}), kRed);
  const int x0 = min_x(px), x1 = max_x(px), mid = (x0 + x1) / 2;
  // Points 4 and 6 are joined to 3 and 7 only: nothing within a tenth of the width of x = 5.
  for (const Pixel& p : px) EXPECT_GT(std::abs(p.x - mid), (x1 - x0) / 20) << "pixel at column " << p.x;
  EXPECT_FALSE(std::isnan(mean_row(px, x0 + (x1 - x0) / 4)));
  EXPECT_FALSE(std::isnan(mean_row(px, x1 - (x1 - x0) / 4)));
  // Infinity is treated the same as NaN.
  y[5] = std::numeric_limits<double>::infinity();
  EXPECT_EQ(pixels_of(plot_lines(std::vector<PlotSeries>{line(x, y)}, PlotOptions{}), kRed).size(), px.size());
}

TEST(Plot, DegenerateRangesStillDraw) {
  const std::vector<PlotSeries> single = {line({3}, {7})};
  EXPECT_GT(pixels_of(plot_lines(single, PlotOptions{}), kRed).size(), 4u);  // a dot
  const std::vector<PlotSeries> flat = {line({0, 1, 2}, {0, 0, 0})};
  const std::vector<Pixel> px = pixels_of(plot_lines(flat, PlotOptions{}), kRed);
  ASSERT_FALSE(px.empty());
  EXPECT_GT(max_x(px) - min_x(px), 400);  // a horizontal line across the plot
}

TEST(Plot, EmptyPlotsDrawBlackAxes) {
  const std::vector<PlotSeries> none;
  const std::vector<PlotSeries> empty = {line({}, {}), line({kNan}, {1})};
  for (const auto& s : {none, empty}) {
    const io::Image8 img = plot_lines(s, PlotOptions{});
    const Box box = find_box(img);
    EXPECT_GE(box.left, 0);
    EXPECT_GT(box.right, box.left);
    EXPECT_GE(box.top, 0);
    EXPECT_GT(box.bottom, box.top);
    EXPECT_TRUE(pixels_of(img, kRed).empty());
  }
}

TEST(Plot, BadOptionsThrowInputErrorNamingTheField) {
  const std::vector<PlotSeries> s = {line({0, 1}, {0, 1})};
  const auto message = [&](const PlotOptions& o, const std::vector<PlotSeries>& series) {
    try {
      plot_lines(series, o);
    } catch (const io::InputError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  PlotOptions o;
  o.width = 63;
  EXPECT_NE(message(o, s).find("width = 63"), std::string::npos) << message(o, s);
  o.width = 8193;
  EXPECT_NE(message(o, s).find("width = 8193"), std::string::npos) << message(o, s);
  o = PlotOptions{};
  o.height = 0;
  EXPECT_NE(message(o, s).find("height = 0"), std::string::npos) << message(o, s);
  const std::vector<PlotSeries> mismatched = {line({0, 1}, {0, 1}), line({0, 1, 2}, {0, 1}, "loss")};
  const std::string m = message(PlotOptions{}, mismatched);
  EXPECT_NE(m.find("series[1] 'loss'"), std::string::npos) << m;
  EXPECT_NE(m.find("y size 2"), std::string::npos) << m;
}

TEST(Plot, TitleIsDrawnAboveTheBox) {
  const auto dark_above_box = [](const std::string& title) {
    PlotOptions o;
    o.title = title;
    const io::Image8 img = plot_lines(std::vector<PlotSeries>{line({0, 1}, {0, 1})}, o);
    const Box box = find_box(img);
    int n = 0;  // middle third only: tick labels may reach above the box at the left
    for (int y = 0; y < box.top; ++y)
      for (int x = img.width / 3; x < 2 * img.width / 3; ++x) n += is_black(img, x, y);
    return n;
  };
  EXPECT_GT(dark_above_box("Loss per step (log)"), 50);
  EXPECT_EQ(dark_above_box(""), 0);
}

TEST(Plot, LegendListsLabelledSeriesTopRight) {
  const auto red_top_right = [](const std::string& label) {
    const io::Image8 img = plot_lines(std::vector<PlotSeries>{line({0, 1}, {0, 0}, label)}, PlotOptions{});
    int n = 0;  // the flat line itself lies at mid height
    for (const Pixel& p : pixels_of(img, kRed)) n += p.x > img.width / 2 && p.y < img.height / 4;
    return n;
  };
  EXPECT_GT(red_top_right("flat"), 20);
  EXPECT_EQ(red_top_right(""), 0);
}

TEST(Plot, SmallestImageWithAllTextDoesNotCrash) {
  PlotOptions o;
  o.width = 64;
  o.height = 64;
  o.title = "a long title that does not fit";
  o.x_label = "x (\xC2\xB5m)";  // UTF-8 micro sign: drawn as one box
  o.y_label = "y";
  const std::vector<PlotSeries> s = {line({0, 1e6}, {-1e-9, 1e9}, "series")};
  const io::Image8 img = plot_lines(s, o);
  EXPECT_EQ(img.pixels.size(), 64u * 64u * 3u);
}

TEST(Plot, PaletteIsDistinctAndCycles) {
  for (int i = 0; i < 8; ++i) {
    EXPECT_EQ(plot_color(i), plot_color(i + 8));
    EXPECT_EQ(plot_color(i), plot_color(i - 8));
    for (int j = 0; j < i; ++j) EXPECT_NE(plot_color(i), plot_color(j)) << i << " " << j;
  }
}

TEST(Plot, TickLabelsAreCompact) {
  EXPECT_EQ(format_tick_label(0.0, 0.5, false), "0");
  EXPECT_EQ(format_tick_label(1e-17, 0.1, false), "0");  // round-off of k * step
  EXPECT_EQ(format_tick_label(0.5, 0.5, false), "0.5");
  EXPECT_EQ(format_tick_label(0.1 + 0.2, 0.1, false), "0.3");
  EXPECT_EQ(format_tick_label(-1.5, 0.5, false), "-1.5");
  EXPECT_EQ(format_tick_label(100.0, 50.0, false), "100");
  EXPECT_EQ(format_tick_label(0.001, 0.001, true), "1e-3");
  EXPECT_EQ(format_tick_label(20000.0, 10000.0, true), "2e+4");
  EXPECT_EQ(format_tick_label(25000.0, 5000.0, true), "2.5e+4");
  EXPECT_EQ(format_tick_label(1e100, 1e100, true), "1e+100");
}

}  // namespace
}  // namespace hisnegs::apps
