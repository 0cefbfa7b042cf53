// SPDX-License-Identifier: Apache-2.0
// Writes the seed corpus of fuzz_vdb into OUT_DIR: small .vdb files of the kinds
// hisnegs reads and writes (a `hisnegs vdb` sparse grid with its background grid,
// and ones OpenVDB writes otherwise: zip or no compression, half floats, an affine
// map, an instance, a vec3s grid, bool and mask grids, a points grid, also
// through hisnegs' writer, with its grid checksums). Built by the `fuzz` preset and
// run by scripts/make-fuzz-corpus.sh; OpenVDB gives each file a random uuid, so
// seeds differ run to run only there.
#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>
#include <openvdb/points/PointConversion.h>

#include <cstdio>
#include <exception>
#include <filesystem>
#include <vector>

#include "io/sparse_grid.hpp"
#include "io/vdb_file.hpp"

namespace {

using namespace openvdb;

// A short tube of voxels: a few leaves, so each seed stays near the 5-4-3 tree's
// fixed topology size (about 10 KB).
template <class GridT>
typename GridT::Ptr tube(typename GridT::ValueType value) {
  auto g = GridT::create();
  auto acc = g->getAccessor();
  for (int x = 0; x < 20; ++x)
    for (int y = 0; y < 3; ++y) acc.setValue(Coord(x, y, x / 4), value);
  return g;
}

void write(const std::filesystem::path& p, const GridPtrVec& grids, std::uint32_t compression) {
  io::File f(p.string());
  f.setCompression(compression);
  f.write(grids);
  f.close();
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: make_vdb_seeds OUT_DIR\n");
    return 2;
  }
  try {
    const std::filesystem::path out = argv[1];
    std::filesystem::create_directories(out);
    hisnegs::io::ensure_openvdb_initialized();

    hisnegs::io::Volume vol;
    vol.nx = 24;
    vol.ny = 12;
    vol.nz = 6;
    vol.voxels.assign(vol.size(), 0.0f);
    for (int x = 2; x < 22; ++x) vol.at(x, 6, 3) = 0.9f;
    vol.source = "seed.tif";
    vol.normalization.method = hisnegs::io::NormalizationMethod::kMinMax;
    hisnegs::io::SparseGridOptions options;
    options.background_fraction = 0.02;
    hisnegs::io::write_vdb(out / "hisnegs.vdb",
                           hisnegs::io::build_sparse_grid(vol, Eigen::Vector3d(1, 0.5, 0.25), options));

    auto f = tube<FloatGrid>(0.5f);
    f->setName("volume");
    write(out / "zip.vdb", {f}, io::COMPRESS_ZIP | io::COMPRESS_ACTIVE_MASK);
    write(out / "raw.vdb", {f}, io::COMPRESS_NONE);
    auto h = tube<FloatGrid>(0.25f);
    h->setName("half");
    h->setSaveFloatAsHalf(true);
    h->setTransform(math::Transform::createLinearTransform(0.5));
    h->transform().postRotate(0.3, math::Y_AXIS);
    auto inst = h->copyGrid();
    inst->setName("instance");
    write(out / "half_instance.vdb", {h, inst}, io::COMPRESS_BLOSC | io::COMPRESS_ACTIVE_MASK);
    auto v = tube<Vec3SGrid>(Vec3s(1, 2, 3));
    v->setName("vectors");
    write(out / "vec3s.vdb", {v}, io::COMPRESS_BLOSC);
    auto b = tube<BoolGrid>(true);
    b->setName("bool");
    auto m = MaskGrid::create();
    m->topologyUnion(*b);
    m->setName("mask");
    write(out / "bits.vdb", {b, m}, io::COMPRESS_BLOSC | io::COMPRESS_ACTIVE_MASK);
    const std::vector<Vec3R> positions{{0, 0, 0}, {1.5, 2, 3}, {-4, 8, 1}};
    auto points = points::createPointDataGrid<points::NullCodec, points::PointDataGrid>(
        positions, *math::Transform::createLinearTransform(0.5));
    points->setName("gaussians");
    write(out / "points.vdb", {points}, io::COMPRESS_BLOSC | io::COMPRESS_ACTIVE_MASK);
    // The same through hisnegs' writer: with the grid checksums that let it be read.
    hisnegs::io::write_vdb_file(out / "hisnegs_points.vdb", {points});
  } catch (const std::exception& e) {
    std::fprintf(stderr, "make_vdb_seeds: %s\n", e.what());
    return 1;
  }
  return 0;
}
