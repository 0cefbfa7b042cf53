// SPDX-License-Identifier: Apache-2.0
// `hisnegs export html` through the real binary, and the page it writes rendered by
// headless Chromium (Debian's `chromium`, software GL via SwiftShader): its
// screenshot of `#view=N&ui=0` must match the CPU hard-MIP render of that view
// (`hisnegs render --mode hard`) to >= 35 dB PSNR; a JS or shader error fails.
// Skips the browser part when /usr/bin/chromium is absent (a failure in CI). Also
// `hisnegs view`: loopback, only "/" served, clean stop on SIGINT, the same page.
#include <gtest/gtest.h>
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <string_view>

#include "apps/viewer/viewer_page.hpp"
#include "gmf/core/checkpoint.hpp"
#include "gmf/core/compact_checkpoint.hpp"
#include "gmf/core/psnr.hpp"
#include "io/png.hpp"
#include "io/tiff_stack.hpp"
#include "splat/camera.hpp"
#include "tests/apps/cli/view_process.hpp"
#include "tests/test_support.hpp"

// Last: OpenSSL headers it pulls in define macros that break Eigen when included before it.
#include <httplib.h>

namespace hisnegs {
namespace {
namespace fs = std::filesystem;
using testing::run_hisnegs;
using testing::served_port;
using testing::ViewProcess;

constexpr const char* kChromium = "/usr/bin/chromium";
// Debian's Chromium 156 in headless mode lays pages out in a viewport at least 500 px
// wide and about 143 px shorter than --window-size (measured: window 500x400 gives
// innerWidth x innerHeight = 500 x 257), while --screenshot captures the window size.
// So the window is made larger than the view by these margins and the screenshot's
// top-left W x H is compared (the page puts its W x H canvas at (0, 0)).
constexpr int kMinWindowWidth = 500;
constexpr int kWindowExtraHeight = 200;
// A hung browser fails the test instead of the suite's timeout.
constexpr int kChromiumTimeoutSeconds = 60;
// The bar for the page against the CPU renderer (8-bit screenshot vs float).
constexpr double kMinPsnrDb = 35.0;

// Skips a test where Chromium is missing; fails it under CI, which installs Chromium.
#define REQUIRE_CHROMIUM()                                                                              \
  do {                                                                                                  \
    if (!fs::exists(kChromium)) {                                                                       \
      if (std::getenv("CI")) FAIL() << kChromium << " is missing; scripts/install-deps.sh installs it"; \
      GTEST_SKIP() << kChromium << " is not installed";                                                 \
    }                                                                                                   \
  } while (false)

// One camera file of the test: intrinsics of its own (non-square, FOV, principal point).
struct CameraCase {
  int width, height;
  double fov_deg, cx_shift, fy_ratio;
};

class CliViewer : public ::testing::Test {
 protected:
  testing::ScratchDir dir_;
  gmf::GaussianMixture mixture_;

  fs::path model() const { return dir_ / "m.ply"; }

  // 40 Gaussians in the unit box: elongated, rotated, intensities 0.1-0.95, a few
  // large enough to overlap (so MAX blending matters).
  void SetUp() override {
    std::mt19937 rng(20);
    std::uniform_real_distribution<float> u(-0.6f, 0.6f), log_scale(std::log(0.02f), std::log(0.15f)), logit(-2.f, 3.f);
    std::normal_distribution<float> quat(0.0f, 1.0f);
    for (int k = 0; k < 40; ++k) {
      gmf::GaussianParams g;
      for (float& v : g.mean) v = u(rng);
      for (float& v : g.log_scale) v = log_scale(rng);
      for (float& v : g.rotation) v = quat(rng);
      g.intensity_logit = logit(rng);
      mixture_.push_back(g);
    }
    gmf::CheckpointMeta meta;
    meta.aspect = std::array<double, 3>{1.0, 1.0, 1.0};
    gmf::save_checkpoint(model(), mixture_, meta);
  }

  // Three orbit views with the intrinsics of `c`, written as cameras.json.
  fs::path write_cameras(const std::string& name, const CameraCase& c) const {
    splat::CameraOptions o;
    o.width = c.width;
    o.height = c.height;
    o.fov_deg = c.fov_deg;
    splat::CameraSet set = splat::custom_orbit(o, {-20.0, 35.0}, {15.0, 130.0});
    set.views.resize(3);
    set.intrinsics.cx += c.cx_shift;
    set.intrinsics.fy *= c.fy_ratio;
    const fs::path path = dir_ / name;
    splat::write_cameras_json(path, set);
    return path;
  }

  // A bright floor (so that 8-bit screenshots resolve it well) up to `top`.
  static gmf::BackgroundModel bright_floor(double top) {
    gmf::BackgroundModel bg;
    bg.values = {0.0, 0.02 * top / 0.15, 0.05 * top / 0.15, 0.1 * top / 0.15, top};
    bg.cdf = {0.5, 0.8, 0.95, 0.99, 1.0};
    bg.samples_per_voxel = 1.6;
    return bg;
  }

  // The page of checkpoint `c` (with a background) draws the floor `render --mode
  // hard` draws, and #background=0 the Gaussians alone.
  void expect_page_floor_as_cpu(const gmf::Checkpoint& c, const std::string& tag) {
    const fs::path model = dir_ / (tag + ".ply"), html = dir_ / (tag + ".html");
    gmf::save_checkpoint(model, c.mixture, c.meta);
    const CameraCase cc{150, 110, 45.0, 4.0, 1.1};
    const fs::path cams = write_cameras(tag + ".json", cc);
    ASSERT_EQ(run_hisnegs({"-q", "export", "html", "--model", model, "--cameras", cams, "-o", html}).exit_code, 0);
    const auto r = run_hisnegs({"-q", "render", "--model", model, "--cameras", cams, "-o", dir_ / ("r" + tag), "--mode",
                                "hard", "--backend", "cpu"});
    ASSERT_EQ(r.exit_code, 0) << r.err;
    const auto n = run_hisnegs({"-q", "render", "--model", model, "--cameras", cams, "-o", dir_ / ("n" + tag), "--mode",
                                "hard", "--background", "none", "--backend", "cpu"});
    ASSERT_EQ(n.exit_code, 0) << n.err;
    const io::Volume with = io::read_tiff_stack(dir_ / ("r" + tag) / "render.tif");
    const io::Volume without = io::read_tiff_stack(dir_ / ("n" + tag) / "render.tif");
    const std::size_t plane = static_cast<std::size_t>(cc.width) * cc.height;
    const std::span<const float> cpu(with.voxels.data() + plane, plane), bare(without.voxels.data() + plane, plane);
    ASSERT_LT(gmf::psnr(cpu, bare), 30.0) << "the floor must show";
    const std::vector<float> page = chromium_view("file://" + html.string() + "#view=1&ui=0", cc.width, cc.height, tag);
    EXPECT_GE(gmf::psnr(std::span<const float>(page.data(), plane), cpu), kMinPsnrDb);
    const std::vector<float> page_bare =
        chromium_view("file://" + html.string() + "#view=1&ui=0&background=0", cc.width, cc.height, tag + "n");
    EXPECT_GE(gmf::psnr(std::span<const float>(page_bare.data(), plane), bare), kMinPsnrDb);
  }

  // Headless Chromium's screenshot of `url` (a `#view=N&ui=0` page of a w x h view):
  // its top-left w x h grey values in [0, 1]. Fails the test on a page error.
  // `log` (if given) gets Chromium's output, console lines included.
  std::vector<float> chromium_view(const std::string& url, int w, int h, const std::string& tag,
                                   std::string* log = nullptr) const {
    const fs::path png = dir_ / ("shot" + tag + ".png");
    const int window_w = std::max(w, kMinWindowWidth), window_h = h + kWindowExtraHeight;
    const testing::ShellResult s = testing::run_shell(
        "timeout " + std::to_string(kChromiumTimeoutSeconds) + " " + kChromium +
        " --headless --no-sandbox --disable-gpu --use-angle=swiftshader --enable-unsafe-swiftshader"
        " --force-device-scale-factor=1 --hide-scrollbars --force-color-profile=srgb --no-first-run"
        " --disable-extensions --user-data-dir=" +
        testing::shell_quoted(dir_ / ("profile" + tag)) + " --window-size=" + std::to_string(window_w) + "," +
        std::to_string(window_h) + " --virtual-time-budget=10000 --enable-logging=stderr --v=0 --screenshot=" +
        testing::shell_quoted(png) + " " + testing::shell_quoted(url));
    EXPECT_EQ(s.status, 0) << s.out;
    EXPECT_EQ(s.out.find("hisnegs-viewer error"), std::string::npos) << s.out;
    EXPECT_EQ(s.out.find("Uncaught"), std::string::npos) << s.out;
    EXPECT_NE(s.out.find("hisnegs-viewer ready"), std::string::npos) << s.out;
    if (log) *log = s.out;
    std::vector<float> page(static_cast<std::size_t>(w) * h, -1.0f);
    if (!fs::exists(png)) return page;
    const io::Image8 shot = io::read_png(png);
    EXPECT_EQ(shot.width, window_w);
    EXPECT_EQ(shot.height, window_h);
    for (int y = 0; y < std::min(h, shot.height); ++y) {
      for (int x = 0; x < std::min(w, shot.width); ++x) {
        const std::size_t at = (static_cast<std::size_t>(y) * shot.width + x) * shot.channels;
        page[static_cast<std::size_t>(y) * w + x] = shot.pixels[at] / 255.0f;
      }
    }
    return page;
  }
};

// The model block of an exported page (base64), or "" when there is none.
std::string model_block(const std::string& html) {
  const std::string open = "<script id=\"hisnegs-model\" type=\"application/octet-stream\">";
  const std::size_t at = html.find(open);
  if (at == std::string::npos) return "";
  return html.substr(at + open.size(), html.find("</script>", at) - at - open.size());
}

TEST_F(CliViewer, ExportHtmlIsSelfContainedAndReportsItsSize) {
  const fs::path cams = write_cameras("c.json", {96, 64, 45.0, 0.0, 1.0});
  // Default: the compact .hgs encoding of the model (no metadata needed by the page).
  const auto r = run_hisnegs({"export", "html", "--model", model(), "--cameras", cams, "-o", dir_ / "v.html"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::string html = testing::read_bytes(dir_ / "v.html");
  EXPECT_NE(r.out.find("export html: wrote"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("40 Gaussians"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("as compact .hgs"), std::string::npos) << r.out;
  const std::string hgs = gmf::encode_compact_checkpoint(mixture_, gmf::CheckpointMeta{});
  EXPECT_EQ(model_block(html), apps::base64_encode(hgs.data(), hgs.size()));
  EXPECT_NE(html.find("\"model_format\":\"hgs\""), std::string::npos);
  // Issue 32, item 12: the model's own cost (the .hgs inside) and the page's, each
  // per Gaussian (before: the page size / K was called the .hgs figure).
  char expected[96];
  std::snprintf(expected, sizeof expected, "as compact .hgs, %.1f B/Gaussian, %.1f in base64",
                static_cast<double>(hgs.size()) / 40.0, static_cast<double>((hgs.size() + 2) / 3 * 4) / 40.0);
  EXPECT_NE(r.out.find(expected), std::string::npos) << r.out << "\nexpected: " << expected;
  std::snprintf(expected, sizeof expected, ", %.1f B/Gaussian (40 Gaussians;", static_cast<double>(html.size()) / 40.0);
  EXPECT_NE(r.out.find(expected), std::string::npos) << r.out << "\nexpected: " << expected;
  EXPECT_NE(html.find("fzstd"), std::string::npos);  // the decoder is inside
  // --float32: the exact parameters, 40 x 10 float32 = 1600 bytes -> 2136 characters.
  const auto f =
      run_hisnegs({"export", "html", "--model", model(), "--cameras", cams, "-o", dir_ / "f.html", "--float32"});
  ASSERT_EQ(f.exit_code, 0) << f.err;
  const std::string exact = testing::read_bytes(dir_ / "f.html");
  const std::vector<float> packed = apps::pack_viewer_model(mixture_);
  EXPECT_EQ(model_block(exact), apps::base64_encode(packed.data(), packed.size() * sizeof(float)));
  EXPECT_EQ(model_block(exact).size(), 2136u);
  EXPECT_NE(exact.find("\"model_format\":\"float32\""), std::string::npos);
  EXPECT_LT(model_block(html).size(), model_block(exact).size());
  // Nothing is loaded (no src= or href=); the script's one fetch (the volume's MIP
  // from `hisnegs view --volume`) is off in an exported page.
  for (const std::string* page : {&html, &exact}) {
    for (const char* needle : {"src=", "href=", "<!--HISNEGS_DATA-->"}) {
      EXPECT_EQ(page->find(needle), std::string::npos) << needle;
    }
    EXPECT_NE(page->find("\"truth\":false"), std::string::npos);
    EXPECT_NE(page->find("\"width\":96"), std::string::npos);
  }
}

TEST_F(CliViewer, ExportHtmlWithoutCamerasHoldsTheEvaluationOrbit) {
  const auto r = run_hisnegs({"export", "html", "--model", model(), "-o", dir_ / "v.html"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("30 views of 256x256 from the evaluation orbit"), std::string::npos) << r.out;
  const std::string html = testing::read_bytes(dir_ / "v.html");
  EXPECT_NE(html.find("\"name\":\"eval_029\""), std::string::npos);
  EXPECT_EQ(html.find("\"name\":\"eval_030\""), std::string::npos);
}

TEST_F(CliViewer, ExportHtmlRefusesBadInputInOneLine) {
  const auto r = run_hisnegs({"export", "html", "--model", dir_ / "missing.ply", "-o", dir_ / "v.html"});
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.err.find("missing.ply"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "v.html"));
  testing::write_text(dir_ / "bad.json", "{\"width\": 4}");
  const auto c =
      run_hisnegs({"export", "html", "--model", model(), "--cameras", dir_ / "bad.json", "-o", dir_ / "v.html"});
  EXPECT_NE(c.exit_code, 0);
  EXPECT_NE(c.err.find("bad.json"), std::string::npos) << c.err;
  EXPECT_FALSE(fs::exists(dir_ / "v.html"));
}

TEST(ViewerPage, Base64MatchesRfc4648) {
  EXPECT_EQ(apps::base64_encode("", 0), "");
  EXPECT_EQ(apps::base64_encode("f", 1), "Zg==");
  EXPECT_EQ(apps::base64_encode("fo", 2), "Zm8=");
  EXPECT_EQ(apps::base64_encode("foo", 3), "Zm9v");
  EXPECT_EQ(apps::base64_encode("foobar", 6), "Zm9vYmFy");
}

TEST(ViewerPage, PackedCovarianceIsTheModelsSigma) {
  gmf::GaussianParams g;
  g.mean = {0.1f, -0.2f, 0.3f};
  g.log_scale = {std::log(0.1f), std::log(0.2f), std::log(0.05f)};
  g.rotation = {2.0f, 0.0f, 0.0f, 0.0f};  // identity after normalization
  g.intensity_logit = 0.0f;
  gmf::GaussianMixture mixture;
  mixture.push_back(g);
  const std::vector<float> p = apps::pack_viewer_model(mixture);
  ASSERT_EQ(p.size(), 10u);
  EXPECT_FLOAT_EQ(p[1], -0.2f);
  EXPECT_NEAR(p[3], 0.01, 1e-7);    // xx = 0.1²
  EXPECT_NEAR(p[4], 0.0, 1e-9);     // xy
  EXPECT_NEAR(p[6], 0.04, 1e-7);    // yy = 0.2²
  EXPECT_NEAR(p[8], 0.0025, 1e-8);  // zz = 0.05²
  EXPECT_FLOAT_EQ(p[9], 0.5f);      // sigmoid(0)
}

// Chromium's screenshot of each `#view=N&ui=0` against `render --mode hard` of view N.
// Issue 33: a model that records its stack's background: the page draws the same
// MIP floor as the CPU hard MIP (`render --mode hard`, the chord of each pixel's ray
// through the box in a fragment shader), and #background=0 draws the Gaussians alone.
TEST_F(CliViewer, ChromiumDrawsTheBackgroundFloorAsTheCpuDoes) {
  REQUIRE_CHROMIUM();
  gmf::Checkpoint c{mixture_, {}};
  c.meta.volume_shape_zyx = std::array<int, 3>{40, 120, 100};
  c.meta.aspect = std::array<double, 3>{0.8, 1.0, 0.6};
  gmf::set_background(c.meta, bright_floor(0.15));
  expect_page_floor_as_cpu(c, "bg");
}

// A background by region (a raw and a subtracted half, a dimmer quarter): the
// page's region shader splits each ray at the region edges as the CPU does.
TEST_F(CliViewer, ChromiumDrawsABackgroundByRegionAsTheCpuDoes) {
  REQUIRE_CHROMIUM();
  gmf::Checkpoint c{mixture_, {}};
  c.meta.volume_shape_zyx = std::array<int, 3>{40, 120, 100};
  c.meta.aspect = std::array<double, 3>{0.8, 1.0, 0.6};
  gmf::BackgroundField field;
  field.regions = gmf::BackgroundRegions::of({100, 120, 40}, 50);  // 2 x 3 x 1
  field.merged = bright_floor(0.15);
  field.models = {bright_floor(0.15), gmf::BackgroundModel{{0.0}, {1.0}, 1.6, 100},
                  bright_floor(0.15), gmf::BackgroundModel{{0.0}, {1.0}, 1.6, 100},
                  bright_floor(0.08), bright_floor(0.2)};
  gmf::set_background(c.meta, field);
  expect_page_floor_as_cpu(c, "rg");
}

TEST_F(CliViewer, ChromiumScreenshotMatchesCpuHardMip) {
  REQUIRE_CHROMIUM();
  // Landscape narrow FOV with an off-centre principal point; portrait wide FOV with
  // fy != fx; a wider landscape at the default FOV.
  const CameraCase cases[] = {{160, 112, 35.0, 7.5, 1.0}, {96, 144, 70.0, 0.0, 1.2}, {200, 120, 50.0, -5.0, 0.9}};
  for (int n = 0; n < 3; ++n) {
    SCOPED_TRACE("camera case " + std::to_string(n) + ", #view=" + std::to_string(n));
    const CameraCase& c = cases[n];
    const std::string tag = std::to_string(n);
    const fs::path cams = write_cameras("c" + tag + ".json", c);
    const fs::path html = dir_ / ("v" + tag + ".html");
    const auto e = run_hisnegs({"export", "html", "--model", model(), "--cameras", cams, "-o", html});
    ASSERT_EQ(e.exit_code, 0) << e.err;
    const auto r = run_hisnegs({"render", "--model", model(), "--cameras", cams, "-o", dir_ / ("r" + tag), "--mode",
                                "hard", "--backend", "cpu"});
    ASSERT_EQ(r.exit_code, 0) << r.err;
    const io::Volume cpu = io::read_tiff_stack(dir_ / ("r" + tag) / "render.tif");
    ASSERT_EQ(cpu.nx, c.width);
    ASSERT_EQ(cpu.ny, c.height);

    const std::string url = "file://" + html.string() + "#view=" + tag + "&ui=0";
    std::string log;
    const auto t0 = std::chrono::steady_clock::now();
    const std::vector<float> page = chromium_view(url, c.width, c.height, tag, &log);
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    EXPECT_NE(log.find("hisnegs-viewer ready: view " + tag + " drawn"), std::string::npos) << log;
    const std::size_t plane = static_cast<std::size_t>(c.width) * c.height;
    const std::span<const float> view(cpu.voxels.data() + n * plane, plane);
    const double db = gmf::psnr(std::span<const float>(page.data(), plane), view);
    float peak = 0.0f;
    for (float v : view) peak = std::max(peak, v);
    EXPECT_GT(peak, 0.2f) << "the view must show the model";
    EXPECT_GE(db, kMinPsnrDb);
    // The comparison discriminates: the same screenshot against another view's render is far off.
    const std::span<const float> other(cpu.voxels.data() + ((n + 1) % 3) * plane, plane);
    EXPECT_LT(gmf::psnr(std::span<const float>(page.data(), plane), other), kMinPsnrDb - 10.0);
    std::printf("view %d: %dx%d, PSNR %.2f dB vs CPU hard MIP, chromium %.2f s, html %zu bytes\n", n, c.width, c.height,
                db, seconds, static_cast<std::size_t>(fs::file_size(html)));
    std::fflush(stdout);  // before the next popen forks a copy of the buffer
  }
}

TEST_F(CliViewer, ViewServesOnlyThePageOnLoopbackAndStopsOnCtrlC) {
  const fs::path cams = write_cameras("c.json", {96, 64, 45.0, 0.0, 1.0});
  ViewProcess view({"view", "--model", model().string(), "--cameras", cams.string(), "--port", "0", "--no-browser"});
  const std::string out = view.read_until("Ctrl-C stops", 20.0);
  const std::string prefix = "at http://127.0.0.1:";  // bound to loopback by default
  const std::size_t at = out.find(prefix);
  ASSERT_NE(at, std::string::npos) << out;
  const int port = std::stoi(out.substr(at + prefix.size()));
  ASSERT_GT(port, 0);

  httplib::Client client("127.0.0.1", port);
  const auto page = client.Get("/");
  ASSERT_TRUE(page) << httplib::to_string(page.error());
  EXPECT_EQ(page->status, 200);
  const std::string hgs = gmf::encode_compact_checkpoint(mixture_, gmf::CheckpointMeta{});
  EXPECT_EQ(model_block(page->body), apps::base64_encode(hgs.data(), hgs.size()));
  EXPECT_NE(page->body.find("\"width\":96"), std::string::npos);
  // Traversal, encoded traversal, absolute and unknown paths: refused, nothing leaks.
  for (const char* path :
       {"/../etc/passwd", "/%2e%2e/%2e%2e/etc/passwd", "//etc/passwd", "/index.html/../../x", "/viewer.js", "/m.ply"}) {
    const auto r = client.Get(path);
    ASSERT_TRUE(r) << path;
    EXPECT_EQ(r->status, 404) << path;
    EXPECT_EQ(r->body.find("root:"), std::string::npos) << path;
    EXPECT_EQ(r->body.find("hisnegs-model"), std::string::npos) << path;
  }
  const auto post = client.Post("/", "x", "text/plain");
  ASSERT_TRUE(post);
  EXPECT_GE(post->status, 400);
  EXPECT_EQ(view.stop(SIGINT, 10.0), 0);
  EXPECT_NE(view.read_until("stopped", 2.0).find("view: stopped (Ctrl-C)"), std::string::npos);
}

// A bad model does not stop the server: one line names it, the page is an error page
// naming it, and once the file is fixed a reload shows the model.
TEST_F(CliViewer, ViewKeepsServingAnErrorPageForABadModelUntilItIsFixed) {
  const fs::path bad = dir_ / "bad.ply";
  testing::write_text(bad, "ply\nformat binary_little_endian 1.0\nelement vertex 99\nend_header\n");
  ViewProcess view({"view", "--model", bad.string(), "--port", "0", "--no-browser"});
  const std::string out = view.read_until("Ctrl-C stops", 20.0);
  const int port = served_port(out);
  ASSERT_GT(port, 0) << out;
  const std::size_t error_at = out.find("view: error: ");
  ASSERT_NE(error_at, std::string::npos) << out;
  const std::string error_line = out.substr(error_at, out.find('\n', error_at) - error_at);
  EXPECT_NE(error_line.find("bad.ply"), std::string::npos) << error_line;

  httplib::Client client("127.0.0.1", port);
  const auto page = client.Get("/");
  ASSERT_TRUE(page) << httplib::to_string(page.error());
  EXPECT_EQ(page->status, 500);
  EXPECT_NE(page->body.find("bad.ply"), std::string::npos) << page->body;
  EXPECT_NE(page->body.find("keeps running"), std::string::npos) << page->body;
  EXPECT_EQ(page->body.find("hisnegs-model"), std::string::npos);

  fs::copy_file(model(), bad, fs::copy_options::overwrite_existing);
  const auto fixed = client.Get("/");
  ASSERT_TRUE(fixed);
  EXPECT_EQ(fixed->status, 200);
  const std::string hgs = gmf::encode_compact_checkpoint(mixture_, gmf::CheckpointMeta{});
  EXPECT_EQ(model_block(fixed->body), apps::base64_encode(hgs.data(), hgs.size()));
  EXPECT_EQ(view.stop(SIGINT, 10.0), 0);
}

TEST_F(CliViewer, ViewWarnsWhenBoundBeyondLoopback) {
  ViewProcess view({"view", "--model", model().string(), "--host", "0.0.0.0", "--port", "0", "--no-browser"});
  const std::string out = view.read_until("Ctrl-C stops", 20.0);
  EXPECT_NE(out.find("view: warning: --host 0.0.0.0 is not loopback"), std::string::npos) << out;
  const int port = served_port(out, "0.0.0.0");
  ASSERT_GT(port, 0) << out;
  httplib::Client client("127.0.0.1", port);
  const auto page = client.Get("/");
  ASSERT_TRUE(page);
  EXPECT_EQ(page->status, 200);
  EXPECT_EQ(view.stop(SIGINT, 10.0), 0);
}

// With --volume, /truth is the CPU ray-marched MIP `gt` renders for the same camera,
// and its PSNR header is the model's CPU hard MIP (`render --mode hard`) against it.
TEST_F(CliViewer, ViewTruthIsTheGroundTruthMipWithTheModelsPsnr) {
  io::Volume vol;
  vol.nx = vol.ny = vol.nz = 24;
  vol.voxels.assign(vol.size(), 0.0f);
  for (int z = 0; z < 24; ++z)
    for (int y = 0; y < 24; ++y)
      for (int x = 0; x < 24; ++x) {
        const double r2 = (x - 11.5) * (x - 11.5) / 30 + (y - 9.0) * (y - 9.0) / 8 + (z - 14.0) * (z - 14.0) / 18;
        vol.at(x, y, z) = static_cast<float>(std::exp(-r2));
      }
  const fs::path stack = dir_ / "v.tif";
  io::write_tiff_stack(stack, vol.voxels, vol.nx, vol.ny, vol.nz);
  const CameraCase c{72, 56, 50.0, 2.0, 1.05};
  const fs::path cams = write_cameras("c.json", c);
  const auto gt = run_hisnegs({"gt", stack, "--cameras", cams, "-o", dir_ / "gt", "--backend", "cpu"});
  ASSERT_EQ(gt.exit_code, 0) << gt.err;
  const auto r = run_hisnegs(
      {"render", "--model", model(), "--cameras", cams, "-o", dir_ / "r", "--mode", "hard", "--backend", "cpu"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const io::Volume mips = io::read_tiff_stack(dir_ / "gt" / "mips.tif");
  const io::Volume renders = io::read_tiff_stack(dir_ / "r" / "render.tif");
  const std::size_t plane = static_cast<std::size_t>(c.width) * c.height;
  ASSERT_EQ(mips.voxels.size(), 3 * plane);

  ViewProcess view({"view", "--model", model().string(), "--volume", stack.string(), "--cameras", cams.string(),
                    "--port", "0", "--no-browser"});
  const std::string out = view.read_until("Ctrl-C stops", 20.0);
  const int port = served_port(out);
  ASSERT_GT(port, 0) << out;
  EXPECT_NE(out.find("compared with the volume's MIP"), std::string::npos) << out;
  httplib::Client client("127.0.0.1", port);
  const auto page = client.Get("/");
  ASSERT_TRUE(page);
  EXPECT_NE(page->body.find("\"truth\":true"), std::string::npos);

  const splat::CameraSet set = splat::read_cameras_json(cams);
  const int n = 1;
  std::ostringstream query;
  query.precision(17);
  query << "/truth?R=";
  for (int i = 0; i < 9; ++i) query << (i ? "," : "") << set.views[n].R_cam_from_world(i / 3, i % 3);
  query << "&T=";
  for (int i = 0; i < 3; ++i) query << (i ? "," : "") << set.views[n].t_cam_from_world(i);
  const auto truth = client.Get(query.str());
  ASSERT_TRUE(truth);
  ASSERT_EQ(truth->status, 200) << truth->body;
  ASSERT_EQ(truth->body.size(), plane * sizeof(float));
  std::vector<float> image(plane);
  std::memcpy(image.data(), truth->body.data(), truth->body.size());
  const std::span<const float> expected(mips.voxels.data() + n * plane, plane);
  EXPECT_GE(gmf::psnr(image, expected), 80.0);  // the same CPU ray marcher
  const std::span<const float> model_view(renders.voxels.data() + n * plane, plane);
  const double psnr = gmf::psnr(model_view, image);
  ASSERT_TRUE(truth->has_header("X-Hisnegs-Psnr"));
  EXPECT_NEAR(std::stod(truth->get_header_value("X-Hisnegs-Psnr")), psnr, 1e-3);

  // A malformed camera: 400 naming the field; the server keeps serving.
  const auto bad = client.Get("/truth?R=1,0,0,0,1,0,0,0&T=0,0,3");
  ASSERT_TRUE(bad);
  EXPECT_EQ(bad->status, 400);
  EXPECT_NE(bad->body.find("field R has 8 numbers, expected 9"), std::string::npos) << bad->body;
  const auto skew = client.Get("/truth?R=1,0,0,0,2,0,0,0,1&T=0,0,3");
  ASSERT_TRUE(skew);
  EXPECT_EQ(skew->status, 400);
  EXPECT_NE(skew->body.find("not a rotation"), std::string::npos) << skew->body;
  const auto again = client.Get(query.str());
  ASSERT_TRUE(again);
  EXPECT_EQ(again->status, 200);
  EXPECT_EQ(view.stop(SIGINT, 10.0), 0);
}

// `#slab=T&offset=O` draws the Gaussians whose centre depth is within O ± T/2 of the
// view's target: the CPU hard MIP with near/far at those depths.
TEST_F(CliViewer, ChromiumSlabMatchesCpuHardMipWithThatDepthRange) {
  REQUIRE_CHROMIUM();
  const CameraCase c{128, 96, 45.0, 0.0, 1.0};
  const fs::path cams = write_cameras("c.json", c);
  splat::CameraSet set = splat::read_cameras_json(cams);
  const int n = 1;
  // The model has no spacing: the slab is in world units about the target (the origin).
  const double depth = set.views[n].center_world().norm(), thick = 0.5, offset = 0.1;
  splat::CameraSet slab = set;
  slab.intrinsics.near = depth + offset - thick / 2;
  slab.intrinsics.far = depth + offset + thick / 2;
  splat::write_cameras_json(dir_ / "slab.json", slab);
  for (const auto& [name, file] : {std::pair{"full", cams}, std::pair{"slab", dir_ / "slab.json"}}) {
    const auto r = run_hisnegs(
        {"render", "--model", model(), "--cameras", file, "-o", dir_ / name, "--mode", "hard", "--backend", "cpu"});
    ASSERT_EQ(r.exit_code, 0) << r.err;
  }
  const io::Volume full = io::read_tiff_stack(dir_ / "full" / "render.tif");
  const io::Volume cut = io::read_tiff_stack(dir_ / "slab" / "render.tif");
  const auto e = run_hisnegs({"export", "html", "--model", model(), "--cameras", cams, "-o", dir_ / "v.html"});
  ASSERT_EQ(e.exit_code, 0) << e.err;
  const std::vector<float> page = chromium_view(
      "file://" + (dir_ / "v.html").string() + "#view=1&ui=0&slab=0.5&offset=0.1", c.width, c.height, "slab");
  const std::size_t plane = static_cast<std::size_t>(c.width) * c.height;
  const std::span<const float> want(cut.voxels.data() + n * plane, plane);
  const std::span<const float> all(full.voxels.data() + n * plane, plane);
  EXPECT_GE(gmf::psnr(page, want), kMinPsnrDb);
  // The slab leaves Gaussians out: the full view is clearly another image.
  EXPECT_LT(gmf::psnr(want, all), kMinPsnrDb - 10.0);
  EXPECT_LT(gmf::psnr(page, all), kMinPsnrDb - 10.0);
}

// RFC 4648 base64 (padded) to bytes; stops at the first character outside the alphabet.
std::string base64_decode(std::string_view text) {
  static const std::string kAlphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  unsigned v = 0;
  int bits = 0;
  for (const char ch : text) {
    const std::size_t d = kAlphabet.find(ch);
    if (d == std::string::npos) break;
    v = (v << 6) | static_cast<unsigned>(d);
    bits += 6;
    if (bits >= 8) {
      bits -= 8;
      out.push_back(static_cast<char>((v >> bits) & 0xff));
    }
  }
  return out;
}

// The text of console line "TAG ..." in Chromium's log (to the closing quote), or "".
std::string console_value(const std::string& log, const std::string& tag) {
  const std::size_t at = log.find("\"" + tag + " ");
  if (at == std::string::npos) return "";
  const std::size_t from = at + tag.size() + 2;
  return log.substr(from, log.find('"', from) - from);
}

// With the UI the page draws at the window's device pixels (the camera's aspect kept,
// its intrinsics scaled, as a screenshot's), not at the camera's size stretched;
// #native=1 (the "camera size" option) draws the camera's own W x H.
TEST_F(CliViewer, TheUiDrawsAtTheWindowsPixelsAndTheCameraSizeOnRequest) {
  REQUIRE_CHROMIUM();
  const CameraCase c{96, 64, 45.0, 0.0, 1.0};
  const fs::path cams = write_cameras("c.json", c);
  const auto e = run_hisnegs({"export", "html", "--model", model(), "--cameras", cams, "-o", dir_ / "d.html"});
  ASSERT_EQ(e.exit_code, 0) << e.err;
  // "hisnegs-viewer bench: T ms/frame over 1 frames, K Gaussians, WxH (window AxB, ...": the drawn size.
  const auto drawn = [&](const std::string& fragment, const std::string& tag) {
    std::string log;
    (void)chromium_view("file://" + (dir_ / "d.html").string() + fragment, c.width, c.height, tag, &log);
    const std::size_t at = log.find("hisnegs-viewer bench:");
    EXPECT_NE(at, std::string::npos) << log.substr(0, 2000);
    std::array<int, 4> v{0, 0, 0, 0};
    const std::size_t g = log.find("Gaussians, ", at);
    if (at == std::string::npos || g == std::string::npos) return v;
    EXPECT_EQ(std::sscanf(log.c_str() + g, "Gaussians, %dx%d (window %dx%d", &v[0], &v[1], &v[2], &v[3]), 4) << log;
    return v;
  };
  const std::array<int, 4> ui = drawn("#view=0&bench=1", "dpr");
  const double fit = std::min<double>(ui[2], ui[3] * 96.0 / 64.0);  // the window's largest 3:2 box
  EXPECT_NEAR(ui[0], fit, 1.0);
  EXPECT_NEAR(ui[1], fit * 64.0 / 96.0, 1.0);
  EXPECT_GT(ui[0], c.width);  // more pixels than the camera has: drawn, not stretched
  const std::array<int, 4> native = drawn("#view=0&bench=1&native=1", "native");
  EXPECT_EQ(native[0], c.width);
  EXPECT_EQ(native[1], c.height);
}

// The page's script API: window.hisnegsViewer.screenshot(w, h) draws the current
// view at another size (the intrinsics scaled with it, as the UI's PNG button does),
// and camera() is the view as a cameras.json that `render` takes. A probe script
// appended to an exported page logs both.
TEST_F(CliViewer, ChromiumScreenshotAtAnotherSizeAndCameraAsCamerasJson) {
  REQUIRE_CHROMIUM();
  const CameraCase c{96, 64, 45.0, 3.0, 1.1};
  const fs::path cams = write_cameras("c.json", c);
  const auto e = run_hisnegs({"export", "html", "--model", model(), "--cameras", cams, "-o", dir_ / "v.html"});
  ASSERT_EQ(e.exit_code, 0) << e.err;
  std::string html = testing::read_bytes(dir_ / "v.html");
  const std::size_t body_end = html.rfind("</body>");
  ASSERT_NE(body_end, std::string::npos);
  html.insert(
      body_end,
      "<script>console.log(\"probe-camera \" + JSON.stringify(window.hisnegsViewer.camera()).replace(/\"/g, \"'\"));"
      "console.log(\"probe-png \" + window.hisnegsViewer.screenshot(150, 80));</script>\n");
  testing::write_text(dir_ / "p.html", html);
  std::string log;
  (void)chromium_view("file://" + (dir_ / "p.html").string() + "#view=1&ui=0", c.width, c.height, "probe", &log);

  // The camera: a cameras.json of view 1 (the page's own intrinsics and pose).
  std::string camera = console_value(log, "probe-camera");
  ASSERT_FALSE(camera.empty()) << log.substr(0, 2000);
  std::replace(camera.begin(), camera.end(), '\'', '"');
  testing::write_text(dir_ / "cam.json", camera);
  const splat::CameraSet got = splat::read_cameras_json(dir_ / "cam.json");
  const splat::CameraSet want = splat::read_cameras_json(cams);
  ASSERT_EQ(got.views.size(), 1u);
  EXPECT_EQ(got.intrinsics.width, c.width);
  EXPECT_EQ(got.intrinsics.height, c.height);
  EXPECT_NEAR(got.intrinsics.fy, want.intrinsics.fy, 1e-9);
  EXPECT_NEAR(got.intrinsics.cx, want.intrinsics.cx, 1e-9);
  EXPECT_LT((got.views[0].R_cam_from_world - want.views[1].R_cam_from_world).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((got.views[0].t_cam_from_world - want.views[1].t_cam_from_world).cwiseAbs().maxCoeff(), 1e-12);

  // The screenshot: 150 x 80 of view 1, against the CPU hard MIP with the intrinsics
  // scaled by 150/96 across and 80/64 down.
  const std::string url = console_value(log, "probe-png");
  const std::string prefix = "data:image/png;base64,";
  ASSERT_EQ(url.rfind(prefix, 0), 0u) << url.substr(0, 80);
  testing::write_text(dir_ / "shot.png", base64_decode(std::string_view(url).substr(prefix.size())));
  const io::Image8 shot = io::read_png(dir_ / "shot.png");
  ASSERT_EQ(shot.width, 150);
  ASSERT_EQ(shot.height, 80);
  splat::CameraSet scaled = want;
  const double sx = 150.0 / c.width, sy = 80.0 / c.height;
  scaled.intrinsics.width = 150;
  scaled.intrinsics.height = 80;
  scaled.intrinsics.fx *= sx;
  scaled.intrinsics.cx *= sx;
  scaled.intrinsics.fy *= sy;
  scaled.intrinsics.cy *= sy;
  scaled.views = {want.views[1], want.views[0]};  // a TIFF stack needs two pages; the first is compared
  splat::write_cameras_json(dir_ / "scaled.json", scaled);
  const auto r = run_hisnegs({"render", "--model", model(), "--cameras", dir_ / "scaled.json", "-o", dir_ / "r",
                              "--mode", "hard", "--backend", "cpu"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const io::Volume cpu = io::read_tiff_stack(dir_ / "r" / "render.tif");
  std::vector<float> page(150 * 80);
  for (std::size_t i = 0; i < page.size(); ++i) page[i] = shot.pixels[i * shot.channels] / 255.0f;
  const std::span<const float> view1(cpu.voxels.data(), page.size());
  EXPECT_GT(*std::max_element(view1.begin(), view1.end()), 0.2f) << "the view must show the model";
  EXPECT_GE(gmf::psnr(page, view1), kMinPsnrDb);
  EXPECT_LT(gmf::psnr(page, std::span<const float>(cpu.voxels.data() + page.size(), page.size())), kMinPsnrDb - 10.0);
}

// The served page is the exported one: Chromium's screenshot of it over HTTP matches
// the CPU hard MIP as the file:// page does.
TEST_F(CliViewer, ViewPageInChromiumMatchesCpuHardMip) {
  REQUIRE_CHROMIUM();
  const CameraCase c{120, 90, 60.0, 3.0, 1.1};
  const fs::path cams = write_cameras("c.json", c);
  const auto r = run_hisnegs(
      {"render", "--model", model(), "--cameras", cams, "-o", dir_ / "r", "--mode", "hard", "--backend", "cpu"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const io::Volume cpu = io::read_tiff_stack(dir_ / "r" / "render.tif");
  ViewProcess view({"view", "--model", model().string(), "--cameras", cams.string(), "--port", "0", "--no-browser"});
  const std::string out = view.read_until("Ctrl-C stops", 20.0);
  const std::size_t at = out.find("at http://");
  ASSERT_NE(at, std::string::npos) << out;
  const std::string url = out.substr(at + 3, out.find(' ', at + 3) - at - 3) + "#view=2&ui=0";
  std::string log;
  const std::vector<float> page = chromium_view(url, c.width, c.height, "served", &log);
  EXPECT_NE(log.find("hisnegs-viewer ready: view 2 drawn"), std::string::npos) << log;
  const std::size_t plane = static_cast<std::size_t>(c.width) * c.height;
  const std::span<const float> ref(cpu.voxels.data() + 2 * plane, plane);
  EXPECT_GE(gmf::psnr(std::span<const float>(page.data(), plane), ref), kMinPsnrDb);
  EXPECT_EQ(view.stop(SIGINT, 10.0), 0);
}

}  // namespace
}  // namespace hisnegs
