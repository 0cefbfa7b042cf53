// SPDX-License-Identifier: Apache-2.0
// Tests of io/detail/tiff_metadata: ImageJ description and OME-XML parsing, units, spacing precedence.
// Pure strings, no files: reading real TIFFs is tiff_stack_test's.
#include "io/detail/tiff_metadata.hpp"

#include <gtest/gtest.h>

#include <string>

#include "io/error.hpp"

namespace hisnegs::io::detail {
namespace {

TEST(TiffMetadataImageJ, ParsesCountsUnitAndSpacing) {
  const ImageJDescription d = parse_imagej_description(
      "ImageJ=1.53t\nimages=120\nchannels=2\nslices=60\nframes=1\nhyperstack=true\nmode=composite\n"
      "unit=um\nspacing=0.9988\nloop=false\nmin=0.0\nmax=255.0\n");
  EXPECT_EQ(d.images, 120);
  EXPECT_EQ(d.channels, 2);
  EXPECT_EQ(d.slices, 60);
  EXPECT_EQ(d.frames, 1);
  EXPECT_TRUE(d.hyperstack);
  EXPECT_EQ(d.unit, "um");
  EXPECT_EQ(d.um_per_unit, 1.0);
  EXPECT_EQ(d.spacing, 0.9988);
  EXPECT_TRUE(d.spacing_error.empty());
}

TEST(TiffMetadataImageJ, MissingKeysStayAbsent) {
  const ImageJDescription d = parse_imagej_description("ImageJ=1.11a\nimages=5\n");
  EXPECT_EQ(d.images, 5);
  EXPECT_FALSE(d.channels);
  EXPECT_FALSE(d.slices);
  EXPECT_FALSE(d.frames);
  EXPECT_FALSE(d.hyperstack);
  EXPECT_FALSE(d.um_per_unit);
  EXPECT_FALSE(d.spacing);
}

TEST(TiffMetadataImageJ, MicronSpellings) {
  for (const char* unit : {"um", "micron", "microns", "\u00B5m", "\xB5m", "\\u00B5m", "\xCE\xBCm", " um\r"}) {
    const ImageJDescription d = parse_imagej_description(std::string("ImageJ=1.11a\nunit=") + unit + "\n");
    EXPECT_EQ(d.um_per_unit, 1.0) << unit;
    EXPECT_TRUE(d.spacing_error.empty()) << unit;
  }
}

TEST(TiffMetadataImageJ, OtherLengthUnits) {
  EXPECT_EQ(parse_imagej_description("ImageJ=\nunit=nm\n").um_per_unit, 1e-3);
  EXPECT_EQ(parse_imagej_description("ImageJ=\nunit=mm\n").um_per_unit, 1e3);
  EXPECT_EQ(parse_imagej_description("ImageJ=\nunit=cm\n").um_per_unit, 1e4);
  EXPECT_EQ(parse_imagej_description("ImageJ=\nunit=inch\n").um_per_unit, 25400.0);
}

TEST(TiffMetadataImageJ, PixelUnitIsUnknownNotAnError) {
  for (const char* text : {"ImageJ=1.11a\nunit=pixel\nspacing=2\n", "ImageJ=1.11a\nspacing=2\n"}) {
    const ImageJDescription d = parse_imagej_description(text);
    EXPECT_FALSE(d.um_per_unit) << text;
    EXPECT_TRUE(d.spacing_error.empty()) << text;
  }
}

TEST(TiffMetadataImageJ, UnknownUnitIsASpacingError) {
  const ImageJDescription d = parse_imagej_description("ImageJ=1.11a\nunit=furlong\n");
  EXPECT_FALSE(d.um_per_unit);
  EXPECT_NE(d.spacing_error.find("unit=furlong"), std::string::npos) << d.spacing_error;
}

TEST(TiffMetadataImageJ, MalformedSpacingIsASpacingError) {
  EXPECT_NE(parse_imagej_description("ImageJ=\nunit=um\nspacing=0.9.9\n").spacing_error.find("spacing=0.9.9"),
            std::string::npos);
  EXPECT_NE(parse_imagej_description("ImageJ=\nunit=um\nspacing=-1\n").spacing_error.find("positive"),
            std::string::npos);
}

TEST(TiffMetadataImageJ, MalformedCountThrowsNamingTheKey) {
  try {
    (void)parse_imagej_description("ImageJ=1.11a\nimages=12\nslices=twelve\n");
    FAIL() << "no InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("slices=twelve"), std::string::npos) << e.what();
  }
  EXPECT_THROW((void)parse_imagej_description("ImageJ=\nchannels=0\n"), InputError);
  EXPECT_THROW((void)parse_imagej_description("ImageJ=\nframes=99999999999\n"), InputError);
}

TEST(TiffMetadataImageJ, Detection) {
  EXPECT_TRUE(is_imagej_description("ImageJ=1.11a\nimages=2\n"));
  EXPECT_FALSE(is_imagej_description("<OME/>"));
  EXPECT_FALSE(is_imagej_description("Created with tifffile"));
}

constexpr const char* kOme =
    "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
    "<!-- <Pixels SizeX='1'> in a comment is not the element -->\n"
    "<OME xmlns=\"http://www.openmicroscopy.org/Schemas/OME/2016-06\">\n"
    "  <Image ID=\"Image:0\">\n"
    "    <Pixels PhysicalSizeXUnit=\"nm\" PhysicalSizeX=\"329.6\" ID=\"Pixels:0\"\n"
    "            PhysicalSizeY = '0.3296' PhysicalSizeZ=\"0.9988\" PhysicalSizeZUnit=\"&#181;m\"\n"
    "            DimensionOrder=\"XYCZT\" Type=\"uint8\" SizeX=\"512\" SizeY=\"256\" SizeZ=\"60\"\n"
    "            SizeC=\"2\" SizeT=\"1\">\n"
    "      <Channel ID=\"Channel:0:0\"/>\n"
    "    </Pixels>\n"
    "  </Image>\n"
    "  <Image ID=\"Image:1\"><Pixels SizeX=\"9\" SizeY=\"9\" DimensionOrder=\"XYZCT\"/></Image>\n"
    "</OME>\n";

TEST(TiffMetadataOme, ParsesTheFirstPixelsElement) {
  EXPECT_TRUE(is_ome_xml(kOme));
  const OmePixels p = parse_ome_pixels(kOme);
  EXPECT_EQ(p.dimension_order, "XYCZT");
  EXPECT_EQ(p.size_x, 512);
  EXPECT_EQ(p.size_y, 256);
  EXPECT_EQ(p.size_z, 60);
  EXPECT_EQ(p.size_c, 2);
  EXPECT_EQ(p.size_time, 1);
  ASSERT_TRUE(p.physical_size_um[0]);
  EXPECT_DOUBLE_EQ(*p.physical_size_um[0], 0.3296);  // 329.6 nm
  EXPECT_DOUBLE_EQ(*p.physical_size_um[1], 0.3296);  // default unit µm
  EXPECT_DOUBLE_EQ(*p.physical_size_um[2], 0.9988);  // &#181;m decoded to µm
  EXPECT_TRUE(p.spacing_error.empty()) << p.spacing_error;
}

TEST(TiffMetadataOme, NamespacePrefixAndSelfClosingElement) {
  const std::string xml =
      "<ome:OME xmlns:ome='x'><ome:Image><ome:Pixels SizeX='4' SizeY='3' SizeZ='2' DimensionOrder='XYZTC' "
      "PhysicalSizeZ='1.5' PhysicalSizeZUnit='mm'/></ome:Image></ome:OME>";
  EXPECT_TRUE(is_ome_xml(xml));
  const OmePixels p = parse_ome_pixels(xml);
  EXPECT_EQ(p.size_x, 4);
  EXPECT_EQ(p.size_c, 1);  // absent Size? default to 1
  EXPECT_EQ(p.dimension_order, "XYZTC");
  EXPECT_FALSE(p.physical_size_um[0]);
  EXPECT_DOUBLE_EQ(*p.physical_size_um[2], 1500.0);
}

TEST(TiffMetadataOme, MalformedSizeThrowsNamingTheAttribute) {
  try {
    (void)parse_ome_pixels("<OME><Pixels SizeX='4' SizeY='3x' DimensionOrder='XYZCT'/></OME>");
    FAIL() << "no InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("SizeY"), std::string::npos) << e.what();
  }
  EXPECT_THROW((void)parse_ome_pixels("<OME><Pixels SizeY='3' DimensionOrder='XYZCT'/></OME>"), InputError);
  EXPECT_THROW((void)parse_ome_pixels("<OME><Pixels SizeX='4' SizeY='3' DimensionOrder='XYZZT'/></OME>"), InputError);
  EXPECT_THROW((void)parse_ome_pixels("<OME><Image/></OME>"), InputError);
  EXPECT_THROW((void)parse_ome_pixels("<OME><Pixels SizeX=4 SizeY='3'/></OME>"), InputError);
}

TEST(TiffMetadataOme, MalformedPhysicalSizeIsASpacingErrorNamingTheAttribute) {
  const OmePixels p = parse_ome_pixels("<OME><Pixels SizeX='4' SizeY='3' PhysicalSizeX='0,33'/></OME>");
  EXPECT_FALSE(p.physical_size_um[0]);
  EXPECT_NE(p.spacing_error.find("PhysicalSizeX=\"0,33\""), std::string::npos) << p.spacing_error;
  const OmePixels q =
      parse_ome_pixels("<OME><Pixels SizeX='4' SizeY='3' PhysicalSizeZ='1' PhysicalSizeZUnit='parsec-ish'/></OME>");
  EXPECT_NE(q.spacing_error.find("PhysicalSizeZUnit"), std::string::npos) << q.spacing_error;
}

TEST(TiffMetadataOme, PixelUnitMeansUncalibrated) {
  const OmePixels p =
      parse_ome_pixels("<OME><Pixels SizeX='4' SizeY='3' PhysicalSizeX='1' PhysicalSizeXUnit='pixel'/></OME>");
  EXPECT_FALSE(p.physical_size_um[0]);
  EXPECT_TRUE(p.spacing_error.empty());
}

TEST(TiffMetadataNumbers, ParseWholeStringsOnly) {
  EXPECT_EQ(parse_double(" 0.9988 "), 0.9988);
  EXPECT_EQ(parse_double("+2e-3"), 2e-3);
  EXPECT_FALSE(parse_double("1.5um"));
  EXPECT_FALSE(parse_double(""));
  EXPECT_EQ(parse_integer("60"), 60);
  EXPECT_FALSE(parse_integer("60.0"));
  EXPECT_FALSE(parse_integer("0x10"));
}

TEST(TiffMetadataSpacing, PrecedenceAxisByAxis) {
  OmePixels ome;
  ome.physical_size_um[0] = 0.5;  // x only
  ImageJDescription ij = parse_imagej_description("ImageJ=\nunit=nm\nspacing=800\n");
  SpacingEvidence e;
  e.ome = &ome;
  e.imagej = &ij;
  e.x_resolution = 1.0;
  e.y_resolution = 0.004;  // pixels per nm -> 0.25 µm
  const VoxelSpacing s = resolve_spacing(e);
  EXPECT_EQ(s.um[0], 0.5);
  EXPECT_EQ(s.source[0], SpacingSource::kOmeXml);
  EXPECT_DOUBLE_EQ(s.um[1], 0.25);
  EXPECT_EQ(s.source[1], SpacingSource::kImageJResolution);
  EXPECT_DOUBLE_EQ(s.um[2], 0.8);
  EXPECT_EQ(s.source[2], SpacingSource::kImageJSpacing);
}

TEST(TiffMetadataSpacing, UserWinsAndSkipsBrokenMetadata) {
  ImageJDescription ij = parse_imagej_description("ImageJ=\nunit=furlong\n");
  SpacingEvidence e;
  e.imagej = &ij;
  EXPECT_THROW((void)resolve_spacing(e), InputError);
  e.user_um = std::array<double, 3>{1, 2, 3};
  const VoxelSpacing s = resolve_spacing(e);
  EXPECT_EQ(s.um, (std::array<double, 3>{1, 2, 3}));
  EXPECT_EQ(s.source[2], SpacingSource::kUser);
}

TEST(TiffMetadataSpacing, ResolutionUnits) {
  SpacingEvidence e;
  e.x_resolution = e.y_resolution = 300;
  e.resolution_unit = 2;  // inch: display DPI, ignored
  EXPECT_EQ(resolve_spacing(e).source[0], SpacingSource::kDefault);
  e.resolution_unit = 1;  // none
  EXPECT_EQ(resolve_spacing(e).source[0], SpacingSource::kDefault);
  e.resolution_unit = 3;  // centimetre
  const VoxelSpacing s = resolve_spacing(e);
  EXPECT_EQ(s.source[0], SpacingSource::kTiffResolution);
  EXPECT_DOUBLE_EQ(s.um[0], 1e4 / 300);
  EXPECT_EQ(s.source[2], SpacingSource::kDefault);
  EXPECT_EQ(s.um[2], 1.0);
}

}  // namespace
}  // namespace hisnegs::io::detail
