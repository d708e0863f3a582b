#include "craftscan/daemon/yaml_document.h"

#include <yaml-cpp/eventhandler.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <charconv>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <vector>

namespace craftscan::daemon {
namespace {

bool Fail(std::string* error, std::string message) {
  if (error) *error = std::move(message);
  return false;
}

// The number of YAML documents in `text`, as YAML::LoadAll counts them, but
// stopping where the parser makes no progress: yaml-cpp 0.7's LoadAll never
// returns on some malformed input (e.g. ",": the parser hands back the same
// empty document forever and the list grows until memory runs out;
// jbeder/yaml-cpp#1040, fixed upstream by #1319). Found by tests/fuzz.
// Throws YAML::Exception on a syntax error, as LoadAll does.
std::size_t CountDocuments(const std::string& text) {
  struct Starts : YAML::EventHandler {
    std::vector<std::size_t> positions;
    void OnDocumentStart(const YAML::Mark& mark) override { positions.push_back(mark.pos); }
    void OnDocumentEnd() override {}
    void OnNull(const YAML::Mark&, YAML::anchor_t) override {}
    void OnAlias(const YAML::Mark&, YAML::anchor_t) override {}
    void OnScalar(const YAML::Mark&, const std::string&, YAML::anchor_t,
                  const std::string&) override {}
    void OnSequenceStart(const YAML::Mark&, const std::string&, YAML::anchor_t,
                         YAML::EmitterStyle::value) override {}
    void OnSequenceEnd() override {}
    void OnMapStart(const YAML::Mark&, const std::string&, YAML::anchor_t,
                    YAML::EmitterStyle::value) override {}
    void OnMapEnd() override {}
  } starts;
  std::istringstream stream(text);
  YAML::Parser parser(stream);
  while (parser.HandleNextDocument(starts)) {
    const std::size_t n = starts.positions.size();
    if (n >= 2 && starts.positions[n - 1] == starts.positions[n - 2]) return n - 1;
  }
  return starts.positions.size();
}

}  // namespace

bool LoadOneYamlDocument(const std::string& text, YAML::Node* root, std::string* error) {
  try {
    const std::size_t documents = CountDocuments(text);
    if (documents > 1) {
      return Fail(
          error, "the configuration must be one YAML document, found " + std::to_string(documents));
    }
    *root = documents == 0 ? YAML::Node() : YAML::Load(text);
  } catch (const YAML::Exception& e) {
    std::string where;
    if (!e.mark.is_null()) {
      where = " at line " + std::to_string(e.mark.line + 1) + ", column " +
              std::to_string(e.mark.column + 1);
    }
    return Fail(error, "YAML syntax error" + where + ": " + e.msg);
  }
  return true;
}

bool CheckConfigRoot(const YAML::Node& root, int version, std::string_view program,
                     std::string* error) {
  const std::string example = "'version: " + std::to_string(version) + "'";
  if (!root.IsDefined() || root.IsNull()) {
    return Fail(error, "empty configuration; expected a mapping starting with " + example);
  }
  if (!root.IsMap()) {
    return Fail(error, "the configuration must be a mapping of keys (e.g. " + example + ")" +
                           AtYamlLine(root));
  }
  const std::string supported =
      "this " + std::string(program) + " reads config version " + std::to_string(version);
  for (const auto& entry : root) {
    if (!entry.first.IsScalar() || entry.first.Scalar() != "version") continue;
    const YAML::Node& value = entry.second;
    const std::string text = value.IsScalar() ? value.Scalar() : "";
    long long number = 0;
    if (ParseConfigInteger(text, &number)) {
      if (number == version) return true;
      return Fail(error,
                  "version: " + text + " is not supported; " + supported + AtYamlLine(value));
    }
    return Fail(error, "version: must be an integer (" + supported + "), got " +
                           (text.empty() ? "nothing" : "'" + text + "'") + AtYamlLine(value));
  }
  return Fail(error, "version: missing; add " + example + " (" + supported + ")");
}

std::string AtYamlLine(const YAML::Node& node) {
  const YAML::Mark mark = node.Mark();
  return mark.is_null() ? std::string() : " (line " + std::to_string(mark.line + 1) + ")";
}

bool ReadConfigText(const std::string& path, std::string* text, std::string* error) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) return Fail(error, path + ": is a directory");
  std::ifstream in(path, std::ios::binary);
  if (!in) return Fail(error, path + ": cannot open: " + std::strerror(errno));
  std::ostringstream out;
  out << in.rdbuf();
  if (in.bad()) return Fail(error, path + ": read error: " + std::strerror(errno));
  *text = out.str();
  return true;
}

bool ParseConfigInteger(std::string_view text, long long* value) {
  const char* end = text.data() + text.size();
  auto [ptr, ec] = std::from_chars(text.data(), end, *value);
  return !text.empty() && ec == std::errc() && ptr == end;
}

bool ParseConfigBool(std::string_view text, bool* value) {
  static constexpr std::array<std::string_view, 4> kTrue = {"true", "yes", "on", "1"};
  static constexpr std::array<std::string_view, 4> kFalse = {"false", "no", "off", "0"};
  if (std::find(kTrue.begin(), kTrue.end(), text) != kTrue.end()) {
    *value = true;
    return true;
  }
  if (std::find(kFalse.begin(), kFalse.end(), text) != kFalse.end()) {
    *value = false;
    return true;
  }
  return false;
}

}  // namespace craftscan::daemon
