// SPDX-License-Identifier: Apache-2.0
#include "tests/io/vdb_fixtures.hpp"

#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>
#include <openvdb/points/PointConversion.h>

#include "io/vdb_file.hpp"

namespace hisnegs::testing {
namespace {

template <class GridT>
typename GridT::Ptr sphere_of(typename GridT::ValueType value, int radius = 12) {
  auto g = GridT::create();
  auto acc = g->getAccessor();
  for (int x = -radius; x <= radius; ++x)
    for (int y = -radius; y <= radius; ++y)
      for (int z = -radius; z <= radius; z += 2)
        if (x * x + y * y + z * z <= radius * radius) acc.setValue(openvdb::Coord(x + 3, y, z), value);
  return g;
}

void write_file(const std::filesystem::path& p, const openvdb::GridPtrVec& grids, std::uint32_t compression,
                const openvdb::MetaMap& file_meta = {}) {
  openvdb::io::File f(p.string());
  f.setCompression(compression);
  f.write(grids, file_meta);
  f.close();
}

}  // namespace

bool vdb_metadata_registered(const std::string& type) {
  io::ensure_openvdb_initialized();
  return openvdb::Metadata::isRegisteredType(type);
}

std::uint32_t openvdb_file_version() { return openvdb::OPENVDB_FILE_VERSION; }

std::vector<std::uint32_t> vdb_compressions() {
  namespace vio = openvdb::io;
  return {vio::COMPRESS_BLOSC | vio::COMPRESS_ACTIVE_MASK, vio::COMPRESS_ZIP | vio::COMPRESS_ACTIVE_MASK,
          vio::COMPRESS_ACTIVE_MASK, vio::COMPRESS_NONE, vio::COMPRESS_BLOSC};
}

EveryKindFile write_every_kind_vdb(const std::filesystem::path& path, std::uint32_t compression) {
  using namespace openvdb;
  io::ensure_openvdb_initialized();
  auto f = sphere_of<FloatGrid>(0.5f);
  f->setName("float");
  f->setTransform(math::Transform::createLinearTransform(0.25));
  auto d = sphere_of<DoubleGrid>(2.0);
  d->setName("double");
  d->setTransform(math::Transform::createLinearTransform(math::Mat4d::identity()));
  d->transform().postRotate(0.3, math::Y_AXIS);  // an affine map
  auto v = sphere_of<Vec3SGrid>(Vec3s(1, 2, 3));
  v->setName("vec3s");
  v->setTransform(math::Transform::Ptr(
      new math::Transform(math::MapBase::Ptr(new math::ScaleTranslateMap(Vec3d(1, 2, 3), Vec3d(0.5, 0, -1))))));
  auto i = sphere_of<Int32Grid>(7);
  i->setName("int32");
  i->setTransform(
      math::Transform::Ptr(new math::Transform(math::MapBase::Ptr(new math::TranslationMap(Vec3d(1, 2, 3))))));
  auto b = sphere_of<BoolGrid>(true);
  b->setName("bool");
  auto m = MaskGrid::create();
  m->topologyUnion(*f);
  m->setName("mask");
  auto h = sphere_of<FloatGrid>(0.25f, 9);
  h->setName("half");
  h->setSaveFloatAsHalf(true);
  h->setTransform(math::Transform::createFrustumTransform(BBoxd(Vec3d(0), Vec3d(10)), 0.5, 2.0, 0.1));
  auto inst = f->copyGrid();  // shares f's tree: written as an instance
  inst->setName("instance");
  MetaMap file_meta;
  file_meta.insertMeta("note", StringMetadata("a file-level string"));
  file_meta.insertMeta("count", Int64Metadata(3));
  file_meta.insertMeta("origin", Vec3DMetadata(Vec3d(1, 2, 3)));
  file_meta.insertMeta("m", Mat4DMetadata(math::Mat4d::identity()));
  const GridPtrVec grids{f, d, v, i, b, m, h, inst};
  write_file(path, grids, compression, file_meta);
  EveryKindFile out;
  for (const auto& g : grids) out.names.push_back(g->getName());
  out.float_leaves = static_cast<std::int64_t>(f->tree().leafCount());
  return out;
}

std::int64_t write_points_vdb(const std::filesystem::path& path, const std::string& name) {
  using namespace openvdb;
  io::ensure_openvdb_initialized();
  const std::vector<Vec3R> positions{{0, 0, 0}, {1.5, 2, 3}, {-4, 8, 1}, {30, 1, -7}};
  const auto xform = math::Transform::createLinearTransform(0.5);
  auto points = points::createPointDataGrid<points::NullCodec, points::PointDataGrid>(positions, *xform);
  points->setName(name);
  write_file(path, GridPtrVec{points}, openvdb::io::COMPRESS_BLOSC | openvdb::io::COMPRESS_ACTIVE_MASK);
  return static_cast<std::int64_t>(points->tree().leafCount());
}

void write_small_vdb(const std::filesystem::path& path) {
  io::ensure_openvdb_initialized();
  auto g = sphere_of<openvdb::FloatGrid>(0.75f, 6);
  g->setName("volume");
  g->insertMeta("source", openvdb::StringMetadata("a.tif"));
  io::write_vdb_file(path, openvdb::GridPtrVec{g});
}

}  // namespace hisnegs::testing
