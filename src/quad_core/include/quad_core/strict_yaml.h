// Strict, typed reading of YAML configs (header-only, ROS-free).
//
// Every component loads its YAML once into a typed struct through StrictYaml. A key that is read but missing,
// a value of the wrong type or out of range, and a key present in the file that nobody read are errors that
// name the full key path and the value (kr_mav_control's silently defaulted misspelt parameters are the
// failure we avoid). Usage:
//
//   quad_core::StrictYaml y = quad_core::StrictYaml::FromFile(path);   // or FromString / FromNode
//   cfg.mass_kg = y.Get<double>("mass_kg", quad_core::Positive());
//   cfg.width = y.Get<int>("camera.width", quad_core::AtLeast(1));
//   cfg.noise = y.GetOr<double>("camera.noise_std_m", 0.0);               // optional key with a default
//   y.CheckAllKeysUsed();                                                  // throws naming unknown keys
#pragma once

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <functional>
#include <optional>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace quad_core {

// Thrown for every config problem; what() names the source, the key path and the offending value.
class ConfigError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// A range check: returns an empty string when the value is fine, else a description of the requirement.
using Check = std::function<std::string(double)>;

inline Check Positive() {
  return [](double v) { return v > 0.0 ? "" : std::string("must be > 0"); };
}
inline Check NonNegative() {
  return [](double v) { return v >= 0.0 ? "" : std::string("must be >= 0"); };
}
inline Check AtLeast(double lo) {
  return [lo](double v) {
    std::ostringstream s;
    s << "must be >= " << lo;
    return v >= lo ? std::string() : s.str();
  };
}
inline Check InRange(double lo, double hi) {
  return [lo, hi](double v) {
    std::ostringstream s;
    s << "must be in [" << lo << ", " << hi << "]";
    return (v >= lo && v <= hi) ? std::string() : s.str();
  };
}

class StrictYaml {
 public:
  static StrictYaml FromFile(const std::string& path) {
    try {
      return StrictYaml(YAML::LoadFile(path), path);
    } catch (const YAML::BadFile&) {
      throw ConfigError(path + ": cannot open config file");
    } catch (const YAML::ParserException& e) {
      throw ConfigError(path + ": YAML syntax error: " + e.what());
    }
  }
  static StrictYaml FromString(const std::string& text, const std::string& source = "<string>") {
    try {
      return StrictYaml(YAML::Load(text), source);
    } catch (const YAML::ParserException& e) {
      throw ConfigError(source + ": YAML syntax error: " + e.what());
    }
  }
  StrictYaml(const YAML::Node& root, std::string source) : root_(root), source_(std::move(source)) {
    if (root_ && !root_.IsNull() && !root_.IsMap()) {
      throw ConfigError(source_ + ": top level must be a mapping of keys to values");
    }
  }

  const std::string& source() const { return source_; }

  bool Has(const std::string& path) const { return Find(path).has_value(); }

  // Required key. T: double, int, bool, std::string, uint64_t, or std::vector of those.
  template <typename T>
  T Get(const std::string& path, const Check& check = nullptr) {
    const auto node = Find(path);
    if (!node) throw ConfigError(source_ + ": missing required key '" + path + "'");
    return Convert<T>(*node, path, check);
  }

  // Optional key: the default when absent (the key is still validated when present).
  template <typename T>
  T GetOr(const std::string& path, const T& fallback, const Check& check = nullptr) {
    const auto node = Find(path);
    if (!node) {
      used_.insert(path);
      return fallback;
    }
    return Convert<T>(*node, path, check);
  }

  // The raw node of a key (e.g. a list of mappings), marked as used with everything below it.
  YAML::Node GetNode(const std::string& path) {
    const auto node = Find(path);
    if (!node) throw ConfigError(source_ + ": missing required key '" + path + "'");
    MarkUsedBelow(*node, path);
    return *node;
  }

  // Throws naming every key in the file that no Get/GetOr/GetNode asked for (typos, stale keys).
  void CheckAllKeysUsed() const {
    std::vector<std::string> unknown;
    CollectUnknown(root_, "", &unknown);
    if (unknown.empty()) return;
    std::string msg = source_ + ": unknown config key(s): ";
    for (size_t i = 0; i < unknown.size(); ++i) msg += (i ? ", '" : "'") + unknown[i] + "'";
    throw ConfigError(msg);
  }

 private:
  std::optional<YAML::Node> Find(const std::string& path) const {
    YAML::Node cur = YAML::Clone(root_);
    size_t start = 0;
    while (true) {
      const size_t dot = path.find('.', start);
      const std::string key = path.substr(start, dot == std::string::npos ? std::string::npos : dot - start);
      if (!cur || !cur.IsMap() || !cur[key]) return std::nullopt;
      cur = cur[key];
      if (dot == std::string::npos) break;
      start = dot + 1;
    }
    return cur;
  }

  template <typename T>
  T Convert(const YAML::Node& node, const std::string& path, const Check& check) {
    used_.insert(path);
    T value;
    try {
      value = node.as<T>();
    } catch (const YAML::Exception&) {
      throw ConfigError(source_ + ": key '" + path + "' has value '" + Dump(node) + "' which is not a " +
                        TypeName<T>());
    }
    if constexpr (std::is_arithmetic_v<T> && !std::is_same_v<T, bool>) {
      if constexpr (std::is_floating_point_v<T>) {
        if (!std::isfinite(value)) {
          throw ConfigError(source_ + ": key '" + path + "' has non-finite value '" + Dump(node) + "'");
        }
      }
      if (check) {
        const std::string why = check(static_cast<double>(value));
        if (!why.empty()) {
          throw ConfigError(source_ + ": key '" + path + "' has value " + Dump(node) + " which " + why);
        }
      }
    }
    if constexpr (std::is_same_v<T, std::vector<double>> || std::is_same_v<T, std::vector<int>>) {
      for (const auto& v : value) {
        if (!std::isfinite(static_cast<double>(v))) {
          throw ConfigError(source_ + ": key '" + path + "' has a non-finite element");
        }
        if (check) {
          const std::string why = check(static_cast<double>(v));
          if (!why.empty()) {
            throw ConfigError(source_ + ": key '" + path + "' has element " + std::to_string(v) + " which " +
                              why);
          }
        }
      }
    }
    return value;
  }

  template <typename T>
  static std::string TypeName() {
    if constexpr (std::is_same_v<T, bool>) return "boolean";
    if constexpr (std::is_integral_v<T>) return "integer";
    if constexpr (std::is_floating_point_v<T>) return "number";
    if constexpr (std::is_same_v<T, std::string>) return "string";
    return "list of the expected type";
  }

  static std::string Dump(const YAML::Node& node) {
    YAML::Emitter e;
    e.SetMapFormat(YAML::Flow);
    e.SetSeqFormat(YAML::Flow);
    e << node;
    return e.c_str();
  }

  void MarkUsedBelow(const YAML::Node& node, const std::string& path) {
    used_.insert(path);
    if (node.IsMap()) {
      for (const auto& kv : node) MarkUsedBelow(kv.second, path + "." + kv.first.as<std::string>());
    }
  }

  void CollectUnknown(const YAML::Node& node, const std::string& prefix,
                      std::vector<std::string>* out) const {
    if (!node || !node.IsMap()) return;
    for (const auto& kv : node) {
      const std::string path =
          prefix.empty() ? kv.first.as<std::string>() : prefix + "." + kv.first.as<std::string>();
      if (used_.count(path)) continue;
      if (kv.second.IsMap() && kv.second.size() > 0) {
        CollectUnknown(kv.second, path, out);
      } else {
        out->push_back(path);
      }
    }
  }

  YAML::Node root_;
  std::string source_;
  std::set<std::string> used_;
};

}  // namespace quad_core
