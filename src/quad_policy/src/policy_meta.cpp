#include "quad_policy/policy_meta.h"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <string>

namespace quad_policy {

const char* ToString(PolicyFrame frame) { return frame == PolicyFrame::kLocal ? "local" : "world"; }

const char* ToString(OutputRepresentation representation) {
  return representation == OutputRepresentation::kPolynomial ? "polynomial" : "bspline";
}

int PolicyMeta::output_dim() const {
  return 3 * (representation == OutputRepresentation::kPolynomial ? poly_degree + 1 : num_ctrl_pts);
}

int PolicyMeta::network_output_dim() const {
  return hypotheses == 1 ? output_dim() : hypotheses * (output_dim() + 1);
}

namespace {

// JSON is a subset of YAML 1.2's flow style, so yaml-cpp (already a dependency) reads the metadata.
class MetaReader {
 public:
  MetaReader(const YAML::Node& root, std::string source) : root_(root), source_(std::move(source)) {}

  YAML::Node Node(const std::string& path) const {
    YAML::Node cur = YAML::Clone(root_);
    std::size_t start = 0;
    while (true) {
      const std::size_t dot = path.find('.', start);
      const std::string key = path.substr(start, dot == std::string::npos ? std::string::npos : dot - start);
      if (!cur.IsMap() || !cur[key]) Fail(path, "is missing");
      cur = cur[key];
      if (dot == std::string::npos) return cur;
      start = dot + 1;
    }
  }

  template <typename T>
  T Get(const std::string& path) const {
    const YAML::Node n = Node(path);
    try {
      return n.as<T>();
    } catch (const YAML::Exception&) {
      Fail(path, "has an unexpected value '" + Dump(n) + "'");
    }
  }

  double PositiveDouble(const std::string& path) const {
    const double v = Get<double>(path);
    if (!(std::isfinite(v) && v > 0.0)) Fail(path, "must be a finite number > 0, got " + Dump(Node(path)));
    return v;
  }

  int IntAtLeast(const std::string& path, int lo) const {
    const int v = Get<int>(path);
    if (v < lo) Fail(path, "must be >= " + std::to_string(lo) + ", got " + std::to_string(v));
    return v;
  }

  // A boolean key that files exported before it existed lack (then `fallback`).
  bool OptionalBool(const std::string& path, bool fallback) const {
    const std::size_t dot = path.rfind('.');
    const YAML::Node parent = dot == std::string::npos ? YAML::Clone(root_) : Node(path.substr(0, dot));
    const std::string key = dot == std::string::npos ? path : path.substr(dot + 1);
    if (!parent.IsMap() || !parent[key]) return fallback;
    const YAML::Node n = parent[key];
    if (n.IsScalar() && (n.Scalar() == "true" || n.Scalar() == "false")) return n.Scalar() == "true";
    Fail(path, "must be true or false, got " + Dump(n));
  }

  // An integer key in [lo, hi] that files exported before it existed lack (then `fallback`).
  int OptionalIntIn(const std::string& path, int lo, int hi, int fallback) const {
    const std::size_t dot = path.rfind('.');
    const YAML::Node parent = dot == std::string::npos ? YAML::Clone(root_) : Node(path.substr(0, dot));
    const std::string key = dot == std::string::npos ? path : path.substr(dot + 1);
    if (!parent.IsMap() || !parent[key]) return fallback;
    const YAML::Node n = parent[key];
    const std::string range =
        "must be an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]";
    // Only what JSON calls an integer: not booleans, fractions or strings (a quoted scalar has the tag "!").
    if (!n.IsScalar() || n.Tag() == "!" || n.Scalar().empty() ||
        n.Scalar().find_first_not_of("-0123456789") != std::string::npos) {
      Fail(path, range + ", got " + Dump(n));
    }
    int v = 0;
    try {
      v = n.as<int>();
    } catch (const YAML::Exception&) {
      Fail(path, range + ", got " + Dump(n));
    }
    if (v < lo || v > hi) Fail(path, range + ", got " + std::to_string(v));
    return v;
  }

  PolicyFrame Frame(const std::string& path) const {
    const std::string s = Get<std::string>(path);
    if (s == "world") return PolicyFrame::kWorld;
    if (s == "local") return PolicyFrame::kLocal;
    Fail(path, "must be 'world' or 'local', got '" + s + "'");
  }

  [[noreturn]] void Fail(const std::string& path, const std::string& what) const {
    throw PolicyFormatError(source_ + ": policy metadata key '" + path + "' " + what);
  }

 private:
  static std::string Dump(const YAML::Node& n) {
    YAML::Emitter e;
    e.SetMapFormat(YAML::Flow);
    e.SetSeqFormat(YAML::Flow);
    e << n;
    return e.c_str();
  }

  YAML::Node root_;
  std::string source_;
};

}  // namespace

PolicyMeta ParsePolicyMeta(const std::string& json_text, const std::string& source) {
  YAML::Node root;
  try {
    root = YAML::Load(json_text);
  } catch (const YAML::Exception& e) {
    throw PolicyFormatError(source + ": policy metadata is not valid JSON: " + e.what());
  }
  if (!root.IsMap()) throw PolicyFormatError(source + ": policy metadata must be a JSON object");
  const MetaReader r(root, source);
  const std::string format = r.Get<std::string>("format");
  if (format != kPolicyMetaFormat) {
    throw PolicyFormatError(source + ": unsupported policy format '" + format + "' (this build reads '" +
                            kPolicyMetaFormat + "')");
  }
  PolicyMeta m;
  m.input_height = r.IntAtLeast("preprocessing.input_height", 8);
  m.input_width = r.IntAtLeast("preprocessing.input_width", 8);
  m.max_depth_m = r.PositiveDouble("preprocessing.max_depth_m");
  m.state_frame = r.Frame("preprocessing.state_frame");
  m.position_scale_m = r.PositiveDouble("preprocessing.position_scale_m");
  m.velocity_scale_mps = r.PositiveDouble("preprocessing.velocity_scale_mps");
  m.velocity_input = r.OptionalBool("preprocessing.velocity_input", true);
  m.num_ctrl_pts = r.IntAtLeast("output.num_ctrl_pts", kPolicyBsplineOrder + 1);
  m.horizon_s = r.PositiveDouble("output.horizon_s");
  const int order = r.Get<int>("output.bspline_order");
  if (order != kPolicyBsplineOrder) {
    r.Fail("output.bspline_order",
           "must be " + std::to_string(kPolicyBsplineOrder) + ", got " + std::to_string(order));
  }
  m.output_frame = r.Frame("output.network_frame");
  const std::string rep = r.Get<std::string>("output.network_representation");
  if (rep == "bspline") {
    m.representation = OutputRepresentation::kBspline;
  } else if (rep == "polynomial") {
    m.representation = OutputRepresentation::kPolynomial;
    m.poly_degree = r.IntAtLeast("model.poly_degree", 1);
  } else {
    r.Fail("output.network_representation", "must be 'bspline' or 'polynomial', got '" + rep + "'");
  }
  m.hypotheses = r.OptionalIntIn("output.hypotheses", 1, kMaxHypotheses, 1);
  const YAML::Node output = r.Node("output");
  if (output["hypotheses_first"]) {
    const std::string first = r.Get<std::string>("output.hypotheses_first");
    if (first != "confidence" && first != "mean") {
      r.Fail("output.hypotheses_first", "must be 'confidence' or 'mean', got '" + first + "'");
    }
    m.mean_first = first == "mean";
  }
  return m;
}

}  // namespace quad_policy
