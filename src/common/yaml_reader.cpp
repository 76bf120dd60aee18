#include "digital_sun_sensor/common/yaml_reader.h"

#include <yaml-cpp/eventhandler.h>
#include <yaml-cpp/parser.h>

#include <sstream>

#include "digital_sun_sensor/common/limits.h"

namespace dss {
namespace {

std::string num(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

std::string joinPath(const std::string& path, const std::string& key) { return path.empty() ? key : path + "." + key; }

// The scalar keys of a mapping, for "known here" lists.
std::string keyList(const YAML::Node& map) {
  std::string out;
  for (const auto& kv : map) out += (out.empty() ? "" : ", ") + kv.first.as<std::string>();
  return out;
}

// Counts the nodes a document expands to, an alias at the size of its anchor's
// node, and stops at the limit: the parser's events arrive before yaml-cpp
// builds (or anyone walks) the tree.
class NodeCounter : public YAML::EventHandler {
 public:
  explicit NodeCounter(std::string origin) : origin_(std::move(origin)) {}

  void OnDocumentStart(const YAML::Mark&) override {}
  void OnDocumentEnd() override {}
  void OnNull(const YAML::Mark&, YAML::anchor_t anchor) override { leaf(anchor); }
  void OnAlias(const YAML::Mark&, YAML::anchor_t anchor) override {
    add(anchor < anchor_nodes_.size() ? anchor_nodes_[anchor] : 1);
  }
  void OnScalar(const YAML::Mark&, const std::string&, YAML::anchor_t anchor, const std::string&) override {
    leaf(anchor);
  }
  void OnSequenceStart(const YAML::Mark&, const std::string&, YAML::anchor_t anchor,
                       YAML::EmitterStyle::value) override {
    open(anchor);
  }
  void OnSequenceEnd() override { close(); }
  void OnMapStart(const YAML::Mark&, const std::string&, YAML::anchor_t anchor, YAML::EmitterStyle::value) override {
    open(anchor);
  }
  void OnMapEnd() override { close(); }

 private:
  void add(std::uint64_t n) {
    nodes_ += n;
    if (nodes_ > limits::kMaxYamlNodes)
      throw YamlError(origin_ + ": more than " + std::to_string(limits::kMaxYamlNodes) +
                      " YAML nodes (aliases counted as what they repeat); refused");
  }
  void remember(YAML::anchor_t anchor, std::uint64_t nodes) {
    if (anchor == YAML::NullAnchor) return;
    if (anchor >= anchor_nodes_.size()) anchor_nodes_.resize(anchor + 1, 1);
    anchor_nodes_[anchor] = nodes;
  }
  void leaf(YAML::anchor_t anchor) {
    add(1);
    remember(anchor, 1);
  }
  void open(YAML::anchor_t anchor) {
    add(1);
    open_.push_back({anchor, nodes_ - 1});
  }
  void close() {
    if (open_.empty()) return;
    remember(open_.back().anchor, nodes_ - open_.back().first_node);
    open_.pop_back();
  }

  struct Open {
    YAML::anchor_t anchor;
    std::uint64_t first_node;
  };
  std::string origin_;
  std::uint64_t nodes_ = 0;
  std::vector<std::uint64_t> anchor_nodes_;  // expanded size by anchor id (ids count up from 1)
  std::vector<Open> open_;
};

}  // namespace

YAML::Node loadYaml(const std::string& text, const std::string& origin) {
  if (text.size() > limits::kMaxYamlFileBytes)
    throw YamlError(origin + ": " + limits::describeBytes(text.size()) + " of YAML, over the limit of " +
                    limits::describeBytes(limits::kMaxYamlFileBytes));
  {
    std::istringstream in(text);
    YAML::Parser parser(in);
    NodeCounter counter(origin);
    while (parser.HandleNextDocument(counter)) {
    }
  }
  return YAML::Load(text);
}

YamlReader::YamlReader(const YAML::Node& root, std::string origin)
    : YamlReader(root, std::move(origin), "", std::make_shared<std::set<std::string>>()) {}

YamlReader::YamlReader(const YAML::Node& node, std::string origin, std::string path,
                       std::shared_ptr<std::set<std::string>> seen)
    : node_(node), origin_(std::move(origin)), path_(std::move(path)), seen_(std::move(seen)) {}

void YamlReader::fail(const std::string& key, const std::string& what) const {
  throw YamlError(origin_ + ": " + join(key) + ": " + what);
}

bool YamlReader::has(const std::string& key) const {
  seen_->insert(join(key));
  return node_.IsMap() && node_[key].IsDefined() && !node_[key].IsNull();
}

YamlReader YamlReader::child(const std::string& key, bool required) const {
  if (!has(key)) {
    if (required) fail(key, "missing required section");
    return YamlReader(YAML::Node(YAML::NodeType::Map), origin_, join(key), seen_);
  }
  if (!node_[key].IsMap()) fail(key, "expected a mapping");
  return YamlReader(node_[key], origin_, join(key), seen_);
}

YamlReader YamlReader::item(const std::string& key, std::size_t index) const {
  const std::string name = key + "[" + std::to_string(index) + "]";
  const YAML::Node list = node_[key];
  if (!list.IsSequence() || index >= list.size()) fail(name, "no such item");
  if (!list[index].IsMap()) fail(name, "expected a mapping");
  return YamlReader(list[index], origin_, join(name), seen_);
}

double YamlReader::checkPositive(const std::string& key, double v) const {
  if (!(v > 0.0)) fail(key, "must be > 0 (got " + num(v) + ")");
  return v;
}

double YamlReader::positive(const std::string& key) const { return checkPositive(key, get<double>(key)); }

double YamlReader::positive(const std::string& key, double fallback) const {
  return checkPositive(key, get<double>(key, fallback));
}

double YamlReader::nonNegative(const std::string& key, double fallback) const {
  const double v = get<double>(key, fallback);
  if (!(v >= 0.0)) fail(key, "must be >= 0 (got " + num(v) + ")");
  return v;
}

double YamlReader::fraction(const std::string& key, double fallback) const {
  const double v = get<double>(key, fallback);
  if (!(v >= 0.0 && v <= 1.0)) fail(key, "must be in [0, 1] (got " + num(v) + ")");
  return v;
}

std::vector<double> YamlReader::positiveList(const std::string& key) const {
  if (!has(key)) fail(key, "missing required key");
  if (!node_[key].IsSequence() || node_[key].size() == 0) fail(key, "expected a non-empty list of numbers");
  std::vector<double> out;
  for (std::size_t i = 0; i < node_[key].size(); ++i) {
    const std::string item = key + "[" + std::to_string(i) + "]";
    const double v = convert<double>(node_[key][i], item);
    if (!(v > 0.0)) fail(item, "must be > 0 (got " + num(v) + ")");
    out.push_back(v);
  }
  return out;
}

void YamlReader::rejectUnknownKeys() const {
  // Depth-first over the document: a key path nobody asked for is unknown.
  struct Walker {
    const YamlReader& reader;
    void map(const YAML::Node& node, const std::string& path) const {
      for (const auto& kv : node) {
        const std::string key = joinPath(path, kv.first.as<std::string>());
        if (!reader.seen_->count(key)) {
          std::string known;
          const std::string prefix = path.empty() ? "" : path + ".";
          for (const auto& s : *reader.seen_) {
            if (s.rfind(prefix, 0) != 0) continue;
            const std::string rest = s.substr(prefix.size());
            if (rest.find('.') == std::string::npos && rest.find('[') == std::string::npos)
              known += (known.empty() ? "" : ", ") + rest;
          }
          throw YamlError(reader.origin_ + ": " + key + ": unknown key" +
                          (known.empty() ? "" : " (known here: " + known + ")"));
        }
        value(kv.second, key);
      }
    }
    void value(const YAML::Node& node, const std::string& path) const {
      if (node.IsMap()) map(node, path);
      if (node.IsSequence())
        for (std::size_t i = 0; i < node.size(); ++i) value(node[i], path + "[" + std::to_string(i) + "]");
    }
  };
  Walker{*this}.value(node_, path_);
}

std::string unknownKeyIn(const YAML::Node& given, const YAML::Node& known) {
  struct Compare {
    static std::string run(const YAML::Node& g, const YAML::Node& k, const std::string& path) {
      if (g.IsMap()) {
        if (!k.IsMap()) return "";  // a value where the writer has none: not a key question
        for (const auto& kv : g) {
          const std::string name = kv.first.as<std::string>();
          const std::string key = joinPath(path, name);
          if (!k[name]) return key + ": unknown key (known here: " + keyList(k) + ")";
          const std::string inner = run(kv.second, k[name], key);
          if (!inner.empty()) return inner;
        }
      } else if (g.IsSequence() && k.IsSequence()) {
        for (std::size_t i = 0; i < g.size() && i < k.size(); ++i) {
          const std::string inner = run(g[i], k[i], path + "[" + std::to_string(i) + "]");
          if (!inner.empty()) return inner;
        }
      }
      return "";
    }
  };
  return Compare::run(given, known, "");
}

}  // namespace dss
