// SPDX-License-Identifier: Apache-2.0
// Line charts drawn into an RGB io::Image8 (for write_png): axes box, nice ticks, labels,
// title and legend, in an embedded bitmap font. Not a plotting library: no markers, bars or fills.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "io/png.hpp"

namespace hisnegs::apps {

// One polyline. Point i is (x[i], y[i]); consecutive drawable points are joined in
// order. A point with a non-finite coordinate (or one <= 0 on a log axis) is not
// drawn and breaks the line; a drawable point with no drawable neighbour is a dot.
struct PlotSeries {
  std::string label;                         // legend text; empty: not in the legend
  std::vector<double> x, y;                  // point coordinates, same length
  std::array<std::uint8_t, 3> rgb{0, 0, 0};  // line colour; plot_color(i) gives a palette
};

struct PlotOptions {
  int width = 800, height = 500;        // image size in pixels, each in [64, 8192]
  std::string title, x_label, y_label;  // empty: not drawn; bytes outside ASCII 32..126 draw as a box
  bool log_y = false;                   // log10 y axis, ticks at decades; points with y <= 0 are skipped
  bool log_x = false;                   // log10 x axis, same rules as log_y
};

// Draws `series` as lines on white, 3 channels, options.width x options.height.
// Axis ranges come from the drawable points of all series (padded when they are
// degenerate); with no drawable point the axes are drawn empty. Text is scaled
// 1x..4x with the image size. Throws io::InputError naming the field and value for a
// width/height outside [64, 8192] or a series whose x and y lengths differ.
io::Image8 plot_lines(std::span<const PlotSeries> series, const PlotOptions& options);

// Colour i of the Okabe-Ito palette (distinct under the common colour-vision
// deficiencies), ordered so the first ones contrast most on white; cycles every 8.
std::array<std::uint8_t, 3> plot_color(int i);

// Tick label for `value` on an axis whose ticks are `step` apart (step > 0): "0",
// fixed notation with the decimals `step` needs ("0.5", "100"), or with `scientific`
// a short exponent form ("1e-3", "2.5e+4"). Exposed for tests and tables beside plots.
std::string format_tick_label(double value, double step, bool scientific);

}  // namespace hisnegs::apps
