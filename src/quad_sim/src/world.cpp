#include "quad_sim/world.h"

#include "quad_sim/math_utils.h"

#include <quad_core/strict_yaml.h>
#include <yaml-cpp/yaml.h>

#include <cmath>
#include <fstream>
#include <random>
#include <sstream>
#include <stdexcept>

namespace quad_sim {

namespace {

constexpr double kPi = 3.14159265358979323846;

// Uniform double in [lo, hi) from the raw 64-bit output (53 random mantissa bits): identical on every
// platform, unlike std::uniform_real_distribution.
double Uniform(std::mt19937_64* rng, double lo, double hi) {
  const double u = static_cast<double>((*rng)() >> 11) * 0x1.0p-53;
  return lo + (hi - lo) * u;
}

std::string Str(const Eigen::Vector3d& v) {
  std::ostringstream s;
  s << "[" << v.x() << ", " << v.y() << ", " << v.z() << "]";
  return s.str();
}

Eigen::Vector3d ReadVector3(quad_core::StrictYaml* y, const std::string& key,
                            const quad_core::Check& check = nullptr) {
  const std::vector<double> v = y->Get<std::vector<double>>(key, check);
  if (v.size() != 3) {
    throw quad_core::ConfigError(y->source() + ": key '" + key + "' must be a list of 3 numbers, got " +
                                 std::to_string(v.size()));
  }
  return Eigen::Vector3d(v[0], v[1], v[2]);
}

void EmitVector(YAML::Emitter* e, const double* v, int n) {
  *e << YAML::Flow << YAML::BeginSeq;
  for (int i = 0; i < n; ++i) *e << v[i];
  *e << YAML::EndSeq;
}

}  // namespace

void World::Validate() const {
  if (!bounds_min_m.allFinite() || !bounds_max_m.allFinite() ||
      (bounds_max_m.array() <= bounds_min_m.array()).any()) {
    throw std::invalid_argument("World: bounds_min_m " + Str(bounds_min_m) +
                                " must be finite and below bounds_max_m " + Str(bounds_max_m));
  }
  for (size_t i = 0; i < boxes.size(); ++i) {
    const OrientedBox& b = boxes[i];
    const std::string name = "World: box " + std::to_string(i);
    if (!b.center_world_m.allFinite()) throw std::invalid_argument(name + " has a non-finite center_m");
    if (!b.q_world_box.coeffs().allFinite() || std::abs(b.q_world_box.norm() - 1.0) > 1e-6) {
      throw std::invalid_argument(name + " has a non-finite or non-unit quaternion");
    }
    if (!b.size_m.allFinite() || (b.size_m.array() <= 0.0).any()) {
      throw std::invalid_argument(name + " has size_m " + Str(b.size_m) + " which must be > 0");
    }
  }
}

bool operator==(const World& a, const World& b) {
  if (a.seed != b.seed || a.bounds_min_m != b.bounds_min_m || a.bounds_max_m != b.bounds_max_m ||
      a.boxes.size() != b.boxes.size()) {
    return false;
  }
  for (size_t i = 0; i < a.boxes.size(); ++i) {
    const OrientedBox& x = a.boxes[i];
    const OrientedBox& y = b.boxes[i];
    if (x.center_world_m != y.center_world_m || x.q_world_box.coeffs() != y.q_world_box.coeffs() ||
        x.size_m != y.size_m) {
      return false;
    }
  }
  return true;
}

int WorldGenConfig::TargetBoxCount() const {
  if (density_boxes_per_100m2 > 0.0) {
    const double area = (bounds_max_m.x() - bounds_min_m.x()) * (bounds_max_m.y() - bounds_min_m.y());
    return static_cast<int>(std::lround(density_boxes_per_100m2 * area / 100.0));
  }
  return num_boxes;
}

void WorldGenConfig::Validate() const {
  auto fail = [](const std::string& what) { throw std::invalid_argument("WorldGenConfig: " + what); };
  if (!bounds_min_m.allFinite() || !bounds_max_m.allFinite() ||
      (bounds_max_m.array() <= bounds_min_m.array()).any()) {
    fail("bounds_min_m " + Str(bounds_min_m) + " must be below bounds_max_m " + Str(bounds_max_m));
  }
  if (num_boxes < 0) fail("num_boxes = " + std::to_string(num_boxes) + " must be >= 0");
  if (!(density_boxes_per_100m2 >= 0.0)) fail("density_boxes_per_100m2 must be >= 0");
  if (!size_min_m.allFinite() || (size_min_m.array() <= 0.0).any()) fail("size_min_m must be > 0");
  if (!size_max_m.allFinite() || (size_max_m.array() < size_min_m.array()).any()) {
    fail("size_max_m " + Str(size_max_m) + " must be >= size_min_m " + Str(size_min_m));
  }
  if (!(center_z_max_m >= center_z_min_m)) fail("center_z_max_m must be >= center_z_min_m");
  if (!(max_roll_deg >= 0.0 && max_roll_deg <= 180.0)) fail("max_roll_deg must be in [0, 180]");
  if (!(max_pitch_deg >= 0.0 && max_pitch_deg <= 90.0)) fail("max_pitch_deg must be in [0, 90]");
  if (!(clear_radius_m >= 0.0)) fail("clear_radius_m must be >= 0");
  if (!(min_gap_m >= 0.0)) fail("min_gap_m must be >= 0");
  if (max_attempts_per_box < 1) fail("max_attempts_per_box must be >= 1");
  for (const ClearZone& z : clear_zones) {
    if (!z.center_world_m.allFinite() || !(z.radius_m >= 0.0))
      fail("clear zone with non-finite centre or radius < 0");
  }
}

World GenerateWorld(const WorldGenConfig& config, uint64_t seed) {
  config.Validate();
  std::mt19937_64 rng(seed);
  World world;
  world.seed = seed;
  world.bounds_min_m = config.bounds_min_m;
  world.bounds_max_m = config.bounds_max_m;
  const int target = config.TargetBoxCount();
  world.boxes.reserve(target);
  std::vector<double> radius;  // bounding-sphere radii, for a cheap gap pre-check
  radius.reserve(target);
  for (int n = 0; n < target; ++n) {
    bool placed = false;
    for (int attempt = 0; attempt < config.max_attempts_per_box && !placed; ++attempt) {
      OrientedBox box;
      for (int i = 0; i < 3; ++i) box.size_m(i) = Uniform(&rng, config.size_min_m(i), config.size_max_m(i));
      box.center_world_m.x() = Uniform(&rng, config.bounds_min_m.x(), config.bounds_max_m.x());
      box.center_world_m.y() = Uniform(&rng, config.bounds_min_m.y(), config.bounds_max_m.y());
      box.center_world_m.z() = Uniform(&rng, config.center_z_min_m, config.center_z_max_m);
      const double roll = Uniform(&rng, -config.max_roll_deg, config.max_roll_deg) * kPi / 180.0;
      const double pitch = Uniform(&rng, -config.max_pitch_deg, config.max_pitch_deg) * kPi / 180.0;
      const double yaw = Uniform(&rng, -kPi, kPi);
      box.q_world_box = QuatFromRpy(roll, pitch, yaw).normalized();
      const double r = box.HalfExtents().norm();

      bool ok = true;
      for (const ClearZone& z : config.clear_zones) {
        if (PointBoxDistance(z.center_world_m, box) <= z.radius_m) {
          ok = false;
          break;
        }
      }
      for (size_t j = 0; ok && j < world.boxes.size(); ++j) {
        const double centre_gap = (world.boxes[j].center_world_m - box.center_world_m).norm() - r - radius[j];
        if (centre_gap >= config.min_gap_m) continue;
        if (BoxBoxDistance(world.boxes[j], box) < config.min_gap_m) ok = false;
      }
      if (ok) {
        world.boxes.push_back(box);
        radius.push_back(r);
        placed = true;
      }
    }
    if (!placed) {
      throw std::runtime_error("GenerateWorld: placed only " + std::to_string(n) + " of " +
                               std::to_string(target) + " boxes (seed " + std::to_string(seed) +
                               "): lower the density or min_gap_m, or " + "raise max_attempts_per_box");
    }
  }
  return world;
}

WorldGenConfig ReadWorldGenConfig(quad_core::StrictYaml* y) {
  using quad_core::NonNegative;
  using quad_core::Positive;
  WorldGenConfig c;
  c.bounds_min_m = ReadVector3(y, "bounds_min_m");
  c.bounds_max_m = ReadVector3(y, "bounds_max_m");
  c.num_boxes = y->Get<int>("num_boxes", NonNegative());
  c.density_boxes_per_100m2 = y->Get<double>("density_boxes_per_100m2", NonNegative());
  c.size_min_m = ReadVector3(y, "size_min_m", Positive());
  c.size_max_m = ReadVector3(y, "size_max_m", Positive());
  c.center_z_min_m = y->Get<double>("center_z_min_m");
  c.center_z_max_m = y->Get<double>("center_z_max_m");
  c.max_roll_deg = y->Get<double>("max_roll_deg", quad_core::InRange(0.0, 180.0));
  c.max_pitch_deg = y->Get<double>("max_pitch_deg", quad_core::InRange(0.0, 90.0));
  c.min_gap_m = y->Get<double>("min_gap_m", NonNegative());
  c.max_attempts_per_box = y->Get<int>("max_attempts_per_box", quad_core::AtLeast(1));
  c.clear_radius_m = y->Get<double>("clear_radius_m", NonNegative());
  const YAML::Node zones = y->GetNode("clear_zone_centers_m");
  if (!zones.IsSequence()) {
    throw quad_core::ConfigError(y->source() + ": key 'clear_zone_centers_m' must be a list of [x, y, z]");
  }
  for (size_t i = 0; i < zones.size(); ++i) {
    std::vector<double> v;
    try {
      v = zones[i].as<std::vector<double>>();
    } catch (const YAML::Exception&) {
      v.clear();
    }
    if (v.size() != 3 || !Eigen::Vector3d(v[0], v[1], v[2]).allFinite()) {
      throw quad_core::ConfigError(y->source() + ": key 'clear_zone_centers_m' element " + std::to_string(i) +
                                   " must be a finite [x, y, z]");
    }
    c.AddClearZone(Eigen::Vector3d(v[0], v[1], v[2]));
  }
  try {
    c.Validate();
  } catch (const std::invalid_argument& e) {
    throw quad_core::ConfigError(y->source() + ": " + e.what());
  }
  return c;
}

std::string WorldToYaml(const World& world) {
  world.Validate();
  YAML::Emitter e;
  e.SetDoublePrecision(17);
  e << YAML::Comment("quad_sim world: ground plane z = 0 plus oriented boxes (quaternions x, y, z, w)");
  e << YAML::BeginMap;
  e << YAML::Key << "format" << YAML::Value << "quad_sim_world";
  e << YAML::Key << "version" << YAML::Value << 1;
  e << YAML::Key << "seed" << YAML::Value << world.seed;
  e << YAML::Key << "bounds_min_m" << YAML::Value;
  EmitVector(&e, world.bounds_min_m.data(), 3);
  e << YAML::Key << "bounds_max_m" << YAML::Value;
  EmitVector(&e, world.bounds_max_m.data(), 3);
  e << YAML::Key << "boxes" << YAML::Value << YAML::BeginSeq;
  for (const OrientedBox& b : world.boxes) {
    e << YAML::Flow << YAML::BeginMap;
    e << YAML::Key << "center_m" << YAML::Value;
    EmitVector(&e, b.center_world_m.data(), 3);
    e << YAML::Key << "q_xyzw" << YAML::Value;
    EmitVector(&e, b.q_world_box.coeffs().data(), 4);  // Eigen stores (x, y, z, w)
    e << YAML::Key << "size_m" << YAML::Value;
    EmitVector(&e, b.size_m.data(), 3);
    e << YAML::EndMap;
  }
  e << YAML::EndSeq << YAML::EndMap;
  if (!e.good()) throw std::runtime_error("WorldToYaml: YAML emitter error: " + e.GetLastError());
  return std::string(e.c_str()) + "\n";
}

namespace {

World WorldFromStrict(quad_core::StrictYaml* y) {
  const std::string format = y->Get<std::string>("format");
  if (format != "quad_sim_world") {
    throw quad_core::ConfigError(y->source() + ": key 'format' has value '" + format +
                                 "' which is not 'quad_sim_world'");
  }
  const int version = y->Get<int>("version");
  if (version != 1) {
    throw quad_core::ConfigError(y->source() + ": key 'version' has value " + std::to_string(version) +
                                 " but this reader supports version 1");
  }
  World w;
  w.seed = y->Get<uint64_t>("seed");
  w.bounds_min_m = ReadVector3(y, "bounds_min_m");
  w.bounds_max_m = ReadVector3(y, "bounds_max_m");
  const YAML::Node boxes = y->GetNode("boxes");
  if (!boxes.IsSequence() && !boxes.IsNull()) {
    throw quad_core::ConfigError(y->source() + ": key 'boxes' must be a list");
  }
  for (size_t i = 0; i < boxes.size(); ++i) {
    quad_core::StrictYaml b(boxes[i], y->source() + ": boxes[" + std::to_string(i) + "]");
    OrientedBox box;
    box.center_world_m = ReadVector3(&b, "center_m");
    const std::vector<double> q = b.Get<std::vector<double>>("q_xyzw");
    if (q.size() != 4)
      throw quad_core::ConfigError(b.source() + ": key 'q_xyzw' must be a list of 4 numbers");
    box.q_world_box = Eigen::Quaterniond(q[3], q[0], q[1], q[2]);
    const double n = box.q_world_box.norm();
    if (n < 1e-6) throw quad_core::ConfigError(b.source() + ": key 'q_xyzw' is a zero quaternion");
    // Hand-written files may carry rounded quaternions; generated ones are unit to the last bit and kept as
    // is.
    if (std::abs(n - 1.0) > 1e-12) box.q_world_box.normalize();
    box.size_m = ReadVector3(&b, "size_m", quad_core::Positive());
    b.CheckAllKeysUsed();
    w.boxes.push_back(box);
  }
  y->CheckAllKeysUsed();
  try {
    w.Validate();
  } catch (const std::invalid_argument& e) {
    throw quad_core::ConfigError(y->source() + ": " + e.what());
  }
  return w;
}

}  // namespace

World WorldFromYaml(const std::string& text, const std::string& source) {
  quad_core::StrictYaml y = quad_core::StrictYaml::FromString(text, source);
  return WorldFromStrict(&y);
}

World LoadWorld(const std::string& path) {
  quad_core::StrictYaml y = quad_core::StrictYaml::FromFile(path);
  return WorldFromStrict(&y);
}

void SaveWorld(const World& world, const std::string& path) {
  const std::string text = WorldToYaml(world);
  std::ofstream f(path);
  if (!f) throw std::runtime_error("SaveWorld: cannot open '" + path + "' for writing");
  f << text;
  if (!f) throw std::runtime_error("SaveWorld: write to '" + path + "' failed");
}

}  // namespace quad_sim
