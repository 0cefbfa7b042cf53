// SPDX-License-Identifier: Apache-2.0
// plot_lines: layout, tick choice, a 5x9 bitmap font and thick clipped lines on an
// RGB io::Image8. Writing the PNG is png.cpp's job.
#include "apps/pipeline/plot.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string_view>
#include <utility>

#include "io/config.hpp"
#include "io/error.hpp"

namespace hisnegs::apps {
namespace {

using Rgb = std::array<std::uint8_t, 3>;
constexpr Rgb kBlack{0, 0, 0}, kWhite{255, 255, 255}, kGridGrey{225, 225, 225};
constexpr int kMinSize = 64, kMaxSize = 8192;

// Font cell in unscaled pixels: 5 columns, rows 0-6 cap height, 7-8 descenders;
// one blank column between glyphs and two blank rows between lines.
constexpr int kGlyphW = 5, kGlyphH = 9, kCapH = 7, kAdvance = 6, kLineH = 11;

// Glyphs for ASCII 32..126, drawn for this file. Row r (top = 0) is the 5 bits at
// 5 * (8 - r), leftmost pixel in the high bit.
constexpr std::array<std::uint64_t, 95> kFont = {
    0x000000000000, 0x042108401000, 0x0A5280000000, 0x0A57D5F52800,  //  !"#
    0x047D1C5F1000, 0x18C888898C00, 0x0C9511593400, 0x042200000000,  // $%&'
    0x022210820800, 0x082084222000, 0x00255D520000, 0x00213E420000,  // ()*+
    0x000000063088, 0x00003E000000, 0x000000063000, 0x010888884000,  // ,-./
    0x0E8CEB98B800, 0x046108423800, 0x0E8844447C00, 0x1F110418B800,  // 0123
    0x0232A5F10800, 0x1F878218B800, 0x06443D18B800, 0x1F0888842000,  // 4567
    0x0E8C5D18B800, 0x0E8C5E113000, 0x006300C60000, 0x006300C61100,  // 89:;
    0x022220820800, 0x0007C1F00000, 0x082082222000, 0x0E8844401000,  // <=>?
    0x0E8DEB683C00, 0x0E8C7F18C400, 0x1E8C7D18F800, 0x0E8C2108B800,  // @ABC
    0x1C9463197000, 0x1F843D087C00, 0x1F843D084000, 0x0E8C2F18BC00,  // DEFG
    0x118C7F18C400, 0x0E2108423800, 0x071084293000, 0x119531494400,  // HIJK
    0x108421087C00, 0x11DD6B18C400, 0x118E6B38C400, 0x0E8C6318B800,  // LMNO
    0x1E8C7D084000, 0x0E8C63593400, 0x1E8C7D494400, 0x0F841C10F800,  // PQRS
    0x1F2108421000, 0x118C6318B800, 0x118C63151000, 0x118C6B5AA800,  // TUVW
    0x118A88A8C400, 0x118A88421000, 0x1F0888887C00, 0x0E4210843800,  // XYZ[
    0x108208208400, 0x0E1084213800, 0x045440000000, 0x0000000003E0,  // \]^_
    0x082080000000, 0x000382F8BC00, 0x1085B318F800, 0x0003A108B800,  // `abc
    0x010B6718BC00, 0x0003A3F83800, 0x064A38842000, 0x0003E318BC2E,  // defg
    0x1085B318C400, 0x040308423800, 0x020184210A4C, 0x1084A98A4800,  // hijk
    0x0C2108423800, 0x0006AB5AD400, 0x0005B318C400, 0x0003A318B800,  // lmno
    0x0007A318FA10, 0x0003E318BC21, 0x0005B3084000, 0x0003E0E0F800,  // pqrs
    0x084710849800, 0x00046319B400, 0x000463151000, 0x0004635AA800,  // tuvw
    0x000454454400, 0x00046318BC2E, 0x0007C4447C00, 0x032110420C00,  // xyz{
    0x042108421080, 0x182104426000, 0x00022A200000,                  // |}~
};
constexpr std::uint64_t kBoxGlyph = 0x1F8C6318FC00;  // any other character

// Half-open pixel rectangle.
struct Rect {
  int x0 = 0, y0 = 0, x1 = 0, y1 = 0;
};

// The image and the rectangle that drawing is confined to (the plot area, for data).
struct Canvas {
  io::Image8& image;
  Rect clip;
  void put(int x, int y, const Rgb& c) const {
    if (x < clip.x0 || x >= clip.x1 || y < clip.y0 || y >= clip.y1) return;
    std::uint8_t* p = &image.pixels[(static_cast<std::size_t>(y) * image.width + x) * 3];
    p[0] = c[0], p[1] = c[1], p[2] = c[2];
  }
  void fill(Rect r, const Rgb& c) const {
    for (int y = r.y0; y < r.y1; ++y)
      for (int x = r.x0; x < r.x1; ++x) put(x, y, c);
  }
};

// UTF-8 continuation bytes are skipped so a multi-byte character draws one box.
bool is_drawn(unsigned char c) { return (c & 0xC0) != 0x80; }

int text_width(std::string_view text, int scale) {
  const auto n = static_cast<int>(
      std::count_if(text.begin(), text.end(), [](char c) { return is_drawn(static_cast<unsigned char>(c)); }));
  return n > 0 ? (n * kAdvance - 1) * scale : 0;
}

// Draws `text` with its cell's top-left at (x, y); `vertical` turns it a quarter
// counter-clockwise (reads bottom to top) with the cell's bottom-left at (x, y).
void draw_text(const Canvas& canvas, int x, int y, std::string_view text, int scale, bool vertical = false) {
  int pen = 0;
  for (const char ch : text) {
    const auto c = static_cast<unsigned char>(ch);
    if (!is_drawn(c)) continue;
    const std::uint64_t bits = (c >= 32 && c <= 126) ? kFont[c - 32] : kBoxGlyph;
    for (int r = 0; r < kGlyphH; ++r)
      for (int col = 0; col < kGlyphW; ++col) {
        if (!((bits >> (5 * (kGlyphH - 1 - r) + (kGlyphW - 1 - col))) & 1u)) continue;
        const int u = (pen + col) * scale, v = r * scale;  // position along / across the text
        for (int dy = 0; dy < scale; ++dy)
          for (int dx = 0; dx < scale; ++dx) {
            if (vertical)
              canvas.put(x + v + dy, y - 1 - u - dx, kBlack);
            else
              canvas.put(x + u + dx, y + v + dy, kBlack);
          }
      }
    pen += kAdvance;
  }
}

// A thick segment: the pixels whose centres lie within `r` of it (a capsule, so
// joints between segments are seamless; a disc when the ends coincide). Pixel
// (i, j) covers [i, i+1) x [j, j+1). Walked along the major axis, a span of
// about 2r per step, so the cost is length x width even for 8192 px images.
// Points come from the axis range, so they lie inside the plot area.
void draw_segment(const Canvas& canvas, double x0, double y0, double x1, double y1, double r, const Rgb& c) {
  const bool steep = std::abs(y1 - y0) > std::abs(x1 - x0);
  // (u, v): u along the major axis, increasing from end a to end b.
  double ua = steep ? y0 : x0, va = steep ? x0 : y0, ub = steep ? y1 : x1, vb = steep ? x1 : y1;
  if (ua > ub) std::swap(ua, ub), std::swap(va, vb);
  const double du = ub - ua, dv = vb - va, length2 = du * du + dv * dv;
  const double slope = du > 0.0 ? dv / du : 0.0, half_span = r * std::sqrt(1.0 + slope * slope) + 1.0;
  for (int u = static_cast<int>(std::floor(ua - r)); u <= static_cast<int>(std::floor(ub + r)); ++u) {
    const double uc = u + 0.5, v_line = va + slope * (std::clamp(uc, ua, ub) - ua);
    const int v0 = static_cast<int>(std::floor(v_line - half_span)),
              v1 = static_cast<int>(std::floor(v_line + half_span));
    for (int v = v0; v <= v1; ++v) {
      const double vc = v + 0.5;
      const double t = length2 > 0.0 ? std::clamp(((uc - ua) * du + (vc - va) * dv) / length2, 0.0, 1.0) : 0.0;
      const double eu = uc - ua - t * du, ev = vc - va - t * dv;
      if (eu * eu + ev * ev <= r * r) canvas.put(steep ? v : u, steep ? u : v, c);
    }
  }
}

// Axis units: log10 of the value on a log axis; NaN marks a point that cannot be drawn.
double to_axis(double v, bool log) {
  if (!std::isfinite(v) || (log && v <= 0.0)) return std::numeric_limits<double>::quiet_NaN();
  return log ? std::log10(v) : v;
}

struct Tick {
  double t;  // axis units
  std::string label;
};

struct Axis {
  double lo = 0.0, hi = 1.0;  // axis units at the plot area's edges
  bool log = false;
  std::vector<Tick> major;
  std::vector<double> minor;  // axis units, unlabelled
};

// Range of the axis from the data range [lo, hi] (lo > hi: no data). Linear axes
// get 4% margins so lines do not run on the box; a degenerate range is widened by
// 10% of its magnitude (1 at zero), a log one by a decade each way. A log axis
// that would show fewer than two decade ticks widens to whole decades instead, so
// it always has labels.
void set_range(Axis& axis, double lo, double hi) {
  if (!(lo <= hi)) lo = 0.0, hi = 1.0;
  const double magnitude = std::max(std::abs(lo), std::abs(hi));
  if (hi - lo <= 1e-9 * magnitude) {
    const double pad = axis.log ? 1.0 : (magnitude > 0.0 ? 0.1 * magnitude : 1.0);
    axis.lo = lo - pad, axis.hi = hi + pad;
    return;
  }
  const double pad = 0.04 * (hi - lo);
  axis.lo = lo - pad, axis.hi = hi + pad;
  if (axis.log && std::floor(axis.hi) - std::ceil(axis.lo) < 1.0) axis.lo = std::floor(lo), axis.hi = std::ceil(hi);
}

// Major ticks, at most about `max_ticks`: multiples of 1, 2 or 5 x 10^n on a
// linear axis, every d-th decade (d = 1, 2, 5, 10, ...) on a log one. Minor ticks
// are the 2..9 multiples when decades are at least `min_decade_px` apart.
void set_ticks(Axis& axis, int max_ticks, double length_px, double min_decade_px) {
  axis.major.clear(), axis.minor.clear();
  const double span = axis.hi - axis.lo;
  if (!std::isfinite(span) || span <= 0.0 || max_ticks < 1) return;
  if (!axis.log) {
    const double raw = span / max_ticks, mag = std::pow(10.0, std::floor(std::log10(raw))), n = raw / mag;
    int mantissa = n <= 1.0 ? 1 : n <= 2.0 ? 2 : n <= 5.0 ? 5 : 10;
    // The step rounded up can leave a single tick in range (span 0.009 at step
    // 0.005 around 0): smaller nice steps until there are two.
    double step = mantissa * mag, k0 = std::ceil(axis.lo / step), k1 = std::floor(axis.hi / step);
    while (k1 - k0 < 1.0 && mantissa > 1) {
      mantissa = mantissa == 10 ? 5 : mantissa == 5 ? 2 : 1;
      step = mantissa * mag, k0 = std::ceil(axis.lo / step), k1 = std::floor(axis.hi / step);
    }
    if (!(k1 - k0 <= 1000.0)) return;
    double max_abs = 0.0;
    for (double k = k0; k <= k1; ++k) max_abs = std::max(max_abs, std::abs(k * step));
    // One notation per axis, so "50000" is not followed by "1e+5".
    const bool scientific = max_abs >= 1e5 || (max_abs > 0.0 && max_abs < 1e-2);
    for (double k = k0; k <= k1; ++k) axis.major.push_back({k * step, format_tick_label(k * step, step, scientific)});
    return;
  }
  const double k0 = std::ceil(axis.lo), k1 = std::floor(axis.hi);
  double stride = 1.0;
  for (int i = 0; (k1 - k0) / stride + 1.0 > max_ticks; ++i) stride = (i % 3 == 1 ? 2.5 : 2.0) * stride;
  for (double k = k0; k <= k1; ++k) {
    if (std::fmod(k, stride) != 0.0) {
      axis.minor.push_back(k);
      continue;
    }
    const double v = std::pow(10.0, k);
    axis.major.push_back({k, format_tick_label(v, v, k < -2.0 || k > 4.0)});
  }
  if (stride != 1.0 || length_px / span < min_decade_px) return;
  // With under two decades in view the decade ticks alone are too sparse to read
  // a value off: 2x and 5x get labels and grid lines as well.
  const bool label_2_5 = k1 - k0 < 2.0 && max_ticks >= 4;
  for (double k = std::floor(axis.lo); k <= axis.hi; ++k)
    for (int m = 2; m <= 9; ++m) {
      const double t = k + std::log10(m);
      if (t < axis.lo || t > axis.hi) continue;
      if (label_2_5 && (m == 2 || m == 5)) {
        const double decade = std::pow(10.0, k);
        axis.major.push_back({t, format_tick_label(m * decade, decade, k < -2.0 || k > 4.0)});
      } else {
        axis.minor.push_back(t);
      }
    }
  std::sort(axis.major.begin(), axis.major.end(), [](const Tick& a, const Tick& b) { return a.t < b.t; });
}

int max_label_width(const Axis& axis, int scale) {
  int w = 0;
  for (const Tick& tick : axis.major) w = std::max(w, text_width(tick.label, scale));
  return w;
}

void require_size(std::string_view field, int value) {
  if (value < kMinSize || value > kMaxSize)
    io::fail_option("plot", field, std::to_string(value),
                "must be in [" + std::to_string(kMinSize) + ", " + std::to_string(kMaxSize) + "] pixels");
}

}  // namespace

std::string format_tick_label(double value, double step, bool scientific) {
  if (!std::isfinite(value) || !(step > 0.0)) return "?";
  if (std::abs(value) < 0.5 * step) return "0";  // also avoids "-0" and 1e-17 from round-off
  const int step_exp = static_cast<int>(std::floor(std::log10(step) + 1e-9));
  char text[512];  // %f of the largest double needs 309 digits
  if (!scientific) {
    std::snprintf(text, sizeof text, "%.*f", std::clamp(-step_exp, 0, 20), value);
    return text;
  }
  const int value_exp = static_cast<int>(std::floor(std::log10(std::abs(value)) + 1e-9));
  std::snprintf(text, sizeof text, "%.*e", std::clamp(value_exp - step_exp, 0, 15), value);
  // "2.50e+04" -> "2.5e+4": trailing mantissa zeros and exponent padding are noise.
  std::string s = text;
  const std::size_t e = s.find('e');
  std::string mantissa = s.substr(0, e), exponent = s.substr(e + 2);
  if (mantissa.find('.') != std::string::npos) {
    while (mantissa.back() == '0') mantissa.pop_back();
    if (mantissa.back() == '.') mantissa.pop_back();
  }
  while (exponent.size() > 1 && exponent.front() == '0') exponent.erase(0, 1);
  return mantissa + 'e' + s[e + 1] + exponent;
}

std::array<std::uint8_t, 3> plot_color(int i) {
  // Okabe & Ito (2008): blue, vermillion, bluish green, reddish purple, orange, sky
  // blue, black, yellow. Yellow is last: it is faint on white.
  static constexpr std::array<Rgb, 8> kPalette = {{{0, 114, 178},
                                                   {213, 94, 0},
                                                   {0, 158, 115},
                                                   {204, 121, 167},
                                                   {230, 159, 0},
                                                   {86, 180, 233},
                                                   {0, 0, 0},
                                                   {240, 228, 66}}};
  const int n = static_cast<int>(kPalette.size());
  return kPalette[static_cast<std::size_t>(((i % n) + n) % n)];
}

namespace {

// The scale of the text and the plot's geometry, shared by the drawing steps.
struct PlotLayout {
  int s = 1;  // text scale: 7 px tall glyphs at 1x
  int pad = 6, gap = 4, tick_len = 5, line_h = kLineH;
  Axis ax, ay;
  Rect area;

  [[nodiscard]] double px(double t) const { return area.x0 + (t - ax.lo) / (ax.hi - ax.lo) * (area.x1 - area.x0); }
  [[nodiscard]] double py(double t) const { return area.y1 - (t - ay.lo) / (ay.hi - ay.lo) * (area.y1 - area.y0); }
  // For ticks: finite t only.
  [[nodiscard]] int ix(double t) const { return static_cast<int>(std::floor(px(t))); }
  [[nodiscard]] int iy(double t) const { return static_cast<int>(std::floor(py(t))); }
};

void check_series(std::span<const PlotSeries> series) {
  for (std::size_t i = 0; i < series.size(); ++i)
    if (series[i].x.size() != series[i].y.size())
      io::fail_option("plot", "series[" + std::to_string(i) + "] '" + io::printable(series[i].label, 40) + "'",
                  "x size " + std::to_string(series[i].x.size()) + ", y size " + std::to_string(series[i].y.size()),
                  "x and y must have the same length");
}

// Axis ranges over the drawable points (NaN on a log axis is skipped).
void fit_ranges(std::span<const PlotSeries> series, Axis& ax, Axis& ay) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  double lo_x = kInf, hi_x = -kInf, lo_y = kInf, hi_y = -kInf;
  for (const PlotSeries& line : series)
    for (std::size_t i = 0; i < line.x.size(); ++i) {
      const double tx = to_axis(line.x[i], ax.log), ty = to_axis(line.y[i], ay.log);
      if (std::isnan(tx) || std::isnan(ty)) continue;
      lo_x = std::min(lo_x, tx), hi_x = std::max(hi_x, tx), lo_y = std::min(lo_y, ty), hi_y = std::max(hi_y, ty);
    }
  set_range(ax, lo_x, hi_x);
  set_range(ay, lo_y, hi_y);
}

// The vertical margins are fixed, so y ticks come first; their labels set the left
// margin, which sets the room for the x ticks.
PlotLayout lay_out(std::span<const PlotSeries> series, const PlotOptions& options) {
  PlotLayout L;
  // Text is 7 px tall at 1x; 2x from 800 x 500 (the default) keeps it readable
  // at the size a report shows the image.
  L.s = std::clamp(std::min(options.width / 400, options.height / 250), 1, 4);
  const int s = L.s;
  L.pad = 6 * s, L.gap = 4 * s, L.tick_len = 5 * s, L.line_h = kLineH * s;
  L.ax.log = options.log_x, L.ay.log = options.log_y;
  fit_ranges(series, L.ax, L.ay);
  const int top = L.pad + (options.title.empty() ? 0 : L.line_h + L.pad);
  const int bottom = s + L.gap + kCapH * s + L.pad + (options.x_label.empty() ? 0 : 2 * L.gap + kCapH * s);
  L.area = Rect{0, top, 0, std::max(top + 8, options.height - bottom)};
  set_ticks(L.ay, std::max(1, (L.area.y1 - L.area.y0) / (30 * s)), L.area.y1 - L.area.y0, 12.0 * s);
  L.area.x0 = L.pad + (options.y_label.empty() ? 0 : L.line_h + L.gap) + max_label_width(L.ay, s) + L.gap + s;
  L.area.x1 = std::max(L.area.x0 + 8, options.width - L.pad - 3 * kAdvance * s);
  const int area_w = L.area.x1 - L.area.x0;
  // Fewer x ticks until neighbouring labels keep two glyphs of space between them.
  for (int n = std::max(1, area_w / (50 * s)); n >= 1; --n) {
    set_ticks(L.ax, n, area_w, 40.0 * s);
    bool fits = true;
    for (std::size_t i = 1; i < L.ax.major.size() && fits; ++i) {
      const int half_labels = (text_width(L.ax.major[i].label, s) + text_width(L.ax.major[i - 1].label, s)) / 2;
      fits = L.px(L.ax.major[i].t) - L.px(L.ax.major[i - 1].t) >= half_labels + 2 * kAdvance * s;
    }
    if (fits) break;
  }
  return L;
}

double line_radius(const PlotLayout& L) { return 0.75 * L.s + 0.25; }  // lines about 2 px wide at 1x

void draw_series(const Canvas& plot, const PlotLayout& L, std::span<const PlotSeries> series) {
  const double radius = line_radius(L);
  for (const PlotSeries& line : series) {
    const auto point = [&](std::size_t i) {
      const double tx = to_axis(line.x[i], L.ax.log), ty = to_axis(line.y[i], L.ay.log);
      return std::array<double, 2>{L.px(tx), L.py(ty)};  // NaN when not drawable
    };
    const auto ok = [](const std::array<double, 2>& p) { return std::isfinite(p[0]) && std::isfinite(p[1]); };
    for (std::size_t i = 0; i < line.x.size(); ++i) {
      const auto p = point(i);
      if (!ok(p)) continue;
      const bool prev = i > 0 && ok(point(i - 1));
      const bool next = i + 1 < line.x.size() && ok(point(i + 1));
      if (next) {
        const auto q = point(i + 1);
        draw_segment(plot, p[0], p[1], q[0], q[1], radius, line.rgb);
      } else if (!prev) {
        draw_segment(plot, p[0], p[1], p[0], p[1], 2.0 * radius, line.rgb);  // isolated: a dot, or it vanishes
      }
    }
  }
}

// The box just outside the plot area (so data never hides it), ticks pointing
// inwards, and the tick labels.
void draw_frame(const Canvas& full, const Canvas& plot, const PlotLayout& L) {
  const Rect& area = L.area;
  const int s = L.s;
  full.fill({area.x0 - s, area.y0 - s, area.x1 + s, area.y0}, kBlack);
  full.fill({area.x0 - s, area.y1, area.x1 + s, area.y1 + s}, kBlack);
  full.fill({area.x0 - s, area.y0, area.x0, area.y1}, kBlack);
  full.fill({area.x1, area.y0, area.x1 + s, area.y1}, kBlack);
  const auto x_tick = [&](double t, int len) { plot.fill({L.ix(t), area.y1 - len, L.ix(t) + s, area.y1}, kBlack); };
  const auto y_tick = [&](double t, int len) { plot.fill({area.x0, L.iy(t), area.x0 + len, L.iy(t) + s}, kBlack); };
  for (const double t : L.ax.minor) x_tick(t, L.tick_len / 2);
  for (const double t : L.ay.minor) y_tick(t, L.tick_len / 2);
  for (const Tick& t : L.ax.major) {
    x_tick(t.t, L.tick_len);
    draw_text(full, L.ix(t.t) - text_width(t.label, s) / 2, area.y1 + s + L.gap, t.label, s);
  }
  for (const Tick& t : L.ay.major) {
    y_tick(t.t, L.tick_len);
    draw_text(full, area.x0 - s - L.gap - text_width(t.label, s), L.iy(t.t) - kCapH * s / 2, t.label, s);
  }
}

void draw_titles(const Canvas& full, const PlotLayout& L, const PlotOptions& options) {
  const int s = L.s;
  const int centre_x = (L.area.x0 + L.area.x1) / 2;
  if (!options.title.empty()) draw_text(full, centre_x - text_width(options.title, s) / 2, L.pad, options.title, s);
  if (!options.x_label.empty())
    draw_text(full, centre_x - text_width(options.x_label, s) / 2, options.height - L.pad - kCapH * s, options.x_label,
              s);
  if (!options.y_label.empty())
    draw_text(full, L.pad, (L.area.y0 + L.area.y1) / 2 + text_width(options.y_label, s) / 2, options.y_label, s, true);
}

// Legend, top right inside the plot area, on top of the data.
void draw_legend(const Canvas& plot, const PlotLayout& L, std::span<const PlotSeries> series) {
  const int s = L.s, gap = L.gap;
  int rows = 0, label_w = 0;
  for (const PlotSeries& line : series)
    if (!line.label.empty()) ++rows, label_w = std::max(label_w, text_width(line.label, s));
  if (rows == 0) return;
  const int sample = 20 * s;
  const Rect box{L.area.x1 - gap - (3 * gap + sample + label_w), L.area.y0 + gap, L.area.x1 - gap,
                 L.area.y0 + gap + 2 * gap + rows * L.line_h - 2 * s};
  plot.fill(box, kBlack);
  plot.fill({box.x0 + s, box.y0 + s, box.x1 - s, box.y1 - s}, kWhite);
  int y = box.y0 + gap;
  for (const PlotSeries& line : series) {
    if (line.label.empty()) continue;
    const double mid = y + kCapH * s / 2.0;
    draw_segment(plot, box.x0 + gap, mid, box.x0 + gap + sample, mid, line_radius(L), line.rgb);
    draw_text(plot, box.x0 + 2 * gap + sample, y, line.label, s);
    y += L.line_h;
  }
}

}  // namespace

io::Image8 plot_lines(std::span<const PlotSeries> series, const PlotOptions& options) {
  require_size("width", options.width);
  require_size("height", options.height);
  check_series(series);
  io::Image8 image;
  image.width = options.width, image.height = options.height, image.channels = 3;
  image.pixels.assign(static_cast<std::size_t>(image.width) * image.height * 3, 255);
  const Canvas full{image, {0, 0, image.width, image.height}};
  const PlotLayout L = lay_out(series, options);
  const Canvas plot{image, L.area};
  for (const Tick& t : L.ax.major) plot.fill({L.ix(t.t), L.area.y0, L.ix(t.t) + 1, L.area.y1}, kGridGrey);
  for (const Tick& t : L.ay.major) plot.fill({L.area.x0, L.iy(t.t), L.area.x1, L.iy(t.t) + 1}, kGridGrey);
  draw_series(plot, L, series);
  draw_frame(full, plot, L);
  draw_titles(full, L, options);
  draw_legend(plot, L, series);
  return image;
}

}  // namespace hisnegs::apps
