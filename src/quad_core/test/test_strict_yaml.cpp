#include <gtest/gtest.h>

#include "quad_core/strict_yaml.h"

using quad_core::ConfigError;
using quad_core::StrictYaml;

namespace {
// Runs f and returns the ConfigError message ("" if none was thrown).
template <typename F>
std::string ErrorOf(F&& f) {
  try {
    f();
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}
}  // namespace

TEST(StrictYaml, ReadsNestedTypedValues) {
  StrictYaml y =
      StrictYaml::FromString("vehicle: {mass_kg: 0.74, rotors: 4, name: falcon}\nlist: [1.0, 2.5]");
  EXPECT_DOUBLE_EQ(y.Get<double>("vehicle.mass_kg"), 0.74);
  EXPECT_EQ(y.Get<int>("vehicle.rotors"), 4);
  EXPECT_EQ(y.Get<std::string>("vehicle.name"), "falcon");
  EXPECT_EQ(y.Get<std::vector<double>>("list"), (std::vector<double>{1.0, 2.5}));
  EXPECT_NO_THROW(y.CheckAllKeysUsed());
}

TEST(StrictYaml, MissingKeyIsNamed) {
  StrictYaml y = StrictYaml::FromString("a: 1", "cfg.yaml");
  EXPECT_EQ(ErrorOf([&] { y.Get<double>("vehicle.mass_kg"); }),
            "cfg.yaml: missing required key 'vehicle.mass_kg'");
}

TEST(StrictYaml, UnknownKeysAreNamed) {
  StrictYaml y = StrictYaml::FromString("mass_kg: 1\nmas_kg: 2\ncam: {width: 3, hieght: 4}", "cfg.yaml");
  y.Get<double>("mass_kg");
  y.Get<int>("cam.width");
  EXPECT_EQ(ErrorOf([&] { y.CheckAllKeysUsed(); }),
            "cfg.yaml: unknown config key(s): 'mas_kg', 'cam.hieght'");
}

TEST(StrictYaml, WrongTypeAndRangeNameKeyAndValue) {
  StrictYaml y = StrictYaml::FromString("mass_kg: heavy\nrate_hz: -5\nx: .nan");
  EXPECT_NE(ErrorOf([&] {
              y.Get<double>("mass_kg");
            }).find("key 'mass_kg' has value 'heavy' which is not a number"),
            std::string::npos);
  EXPECT_NE(
      ErrorOf([&] { y.Get<double>("rate_hz", quad_core::Positive()); }).find("value -5 which must be > 0"),
      std::string::npos);
  EXPECT_NE(ErrorOf([&] { y.Get<double>("x"); }).find("non-finite"), std::string::npos);
}

TEST(StrictYaml, OptionalKeyFallsBackButIsStillChecked) {
  StrictYaml y = StrictYaml::FromString("noise: -1");
  EXPECT_DOUBLE_EQ(y.GetOr<double>("absent", 2.0), 2.0);
  EXPECT_NE(ErrorOf([&] { y.GetOr<double>("noise", 0.0, quad_core::NonNegative()); }), "");
}

TEST(StrictYaml, MissingFileIsNamed) {
  EXPECT_EQ(ErrorOf([] { StrictYaml::FromFile("/nonexistent/x.yaml"); }),
            "/nonexistent/x.yaml: cannot open config file");
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
