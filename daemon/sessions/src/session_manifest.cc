#include "craftscan/daemon/session_manifest.h"

#include <array>
#include <cstdio>
#include <set>
#include <utility>

namespace craftscan::daemon {
namespace {

using Json = nlohmann::json;
using OrderedJson = nlohmann::ordered_json;

constexpr std::array<std::pair<SessionState, const char*>, 6> kStateNames{{
    {SessionState::kCreated, "created"},
    {SessionState::kCapturing, "capturing"},
    {SessionState::kReconstructing, "reconstructing"},
    {SessionState::kDone, "done"},
    {SessionState::kInterrupted, "interrupted"},
    {SessionState::kFailed, "failed"},
}};

constexpr std::size_t kMaxObjectBytes = 64;

bool IsNameChar(char c) {
  return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '.' ||
         c == '_' || c == '-';
}
bool IsAlnum(char c) { return IsNameChar(c) && c != '.' && c != '_' && c != '-'; }
bool IsDigit(char c) { return c >= '0' && c <= '9'; }

std::string Hex(std::uint64_t value) {
  char text[17];
  std::snprintf(text, sizeof text, "%016llx", static_cast<unsigned long long>(value));
  return text;
}

bool ParseHex(const std::string& text, std::uint64_t* value) {
  if (text.size() != 16) return false;
  std::uint64_t v = 0;
  for (const char c : text) {
    int digit;
    if (c >= '0' && c <= '9') {
      digit = c - '0';
    } else if (c >= 'a' && c <= 'f') {
      digit = c - 'a' + 10;
    } else {
      return false;
    }
    v = (v << 4) | static_cast<std::uint64_t>(digit);
  }
  *value = v;
  return true;
}

OrderedJson RecordJson(const FileRecord& r) {
  OrderedJson j{{"size", r.size_bytes}, {"fnv1a64", Hex(r.fnv1a64)}};
  if (!r.sha256.empty()) j["sha256"] = r.sha256;
  return j;
}

bool IsLowerHex(const std::string& text, std::size_t digits) {
  return text.size() == digits && text.find_first_not_of("0123456789abcdef") == std::string::npos;
}

// Field readers for ManifestFromJson: each throws ParseError naming the field.
struct ParseError {
  std::string what;
};

const Json& Field(const Json& object, const char* key, const std::string& where) {
  const auto it = object.find(key);
  if (it == object.end()) throw ParseError{where + "." + key + " is missing"};
  return *it;
}

std::string String(const Json& object, const char* key, const std::string& where) {
  const Json& v = Field(object, key, where);
  if (!v.is_string()) throw ParseError{where + "." + key + " is not a string"};
  return v.get<std::string>();
}

const Json& Object(const Json& object, const char* key, const std::string& where) {
  const Json& v = Field(object, key, where);
  if (!v.is_object()) throw ParseError{where + "." + key + " is not an object"};
  return v;
}

FileRecord Record(const Json& v, const std::string& where) {
  if (!v.is_object()) throw ParseError{where + " is not an object"};
  const Json& size = Field(v, "size", where);
  if (!size.is_number_unsigned()) throw ParseError{where + ".size is not a non-negative integer"};
  FileRecord r;
  r.size_bytes = size.get<std::uint64_t>();
  if (!ParseHex(String(v, "fnv1a64", where), &r.fnv1a64)) {
    throw ParseError{where + ".fnv1a64 is not 16 lower-case hex digits"};
  }
  if (v.contains("sha256")) {  // absent in manifests from before SHA-256
    r.sha256 = String(v, "sha256", where);
    if (!IsLowerHex(r.sha256, 64)) {
      throw ParseError{where + ".sha256 is not 64 lower-case hex digits"};
    }
  }
  return r;
}

void ParseManifest(const Json& j, Manifest* m) {
  const std::string top = "manifest";
  if (!j.is_object()) throw ParseError{"manifest is not a JSON object"};
  if (String(j, "format", top) != "craftscan-session") {
    throw ParseError{"manifest.format is not \"craftscan-session\""};
  }
  const Json& version = Field(j, "format_version", top);
  if (!version.is_number_integer() || version.get<int>() != Manifest::kFormatVersion) {
    throw ParseError{"manifest.format_version " + version.dump() + " is not supported (expected " +
                     std::to_string(Manifest::kFormatVersion) + ")"};
  }
  m->format_version = Manifest::kFormatVersion;
  m->id = String(j, "id", top);
  if (!IsValidSessionId(m->id)) throw ParseError{"manifest.id '" + m->id + "' is not a session id"};
  const Json& object = Object(j, "object", top);
  m->object_name = String(object, "name", "manifest.object");
  m->object = String(object, "sanitized", "manifest.object");
  m->job = String(j, "job", top);
  m->params = Object(j, "params", top);
  const std::string state = String(j, "state", top);
  if (!SessionStateFromString(state, &m->state)) {
    throw ParseError{"manifest.state '" + state + "' is not a session state"};
  }
  m->error = String(j, "error", top);
  m->created_utc = String(j, "created", top);
  m->updated_utc = String(j, "updated", top);

  const Json& calibration = Field(j, "calibration", top);
  m->calibration.reset();
  m->calibration_id.clear();
  if (!calibration.is_null()) {
    m->calibration = Record(calibration, "manifest.calibration");
    m->calibration_id = String(calibration, "id", "manifest.calibration");
  }

  const Json& views = Field(j, "views", top);
  if (!views.is_array()) throw ParseError{"manifest.views is not an array"};
  m->views.clear();
  static const std::set<std::string> kViewFiles{kLeftPng,    kRightPng,     kMetaJson,
                                                kTexturePng, kDisparityPfm, kCloudPly};
  for (std::size_t i = 0; i < views.size(); ++i) {
    const std::string where = "manifest.views[" + std::to_string(i) + "]";
    const Json& v = views[i];
    if (!v.is_object()) throw ParseError{where + " is not an object"};
    ViewRecord view;
    const Json& index = Field(v, "index", where);
    if (!index.is_number_integer() || index.get<long long>() < 0 ||
        index.get<long long>() > kMaxViewIndex) {
      throw ParseError{where + ".index is not an integer in 0.." + std::to_string(kMaxViewIndex)};
    }
    view.index = index.get<int>();
    const Json& angle = Field(v, "angle_deg", where);
    if (!angle.is_number()) throw ParseError{where + ".angle_deg is not a number"};
    view.angle_deg = angle.get<double>();
    view.captured_utc = String(v, "captured", where);
    for (const auto& [name, record] : Object(v, "files", where).items()) {
      if (kViewFiles.count(name) == 0)
        throw ParseError{where + ".files has unknown file '" + name + "'"};
      view.files[name] = Record(record, where + ".files." + name);
    }
    if (!m->views.emplace(view.index, std::move(view)).second) {
      throw ParseError{where + ".index " + index.dump() + " appears twice"};
    }
  }

  m->outputs.clear();
  for (const auto& [name, record] : Object(j, "outputs", top).items()) {
    std::string why;
    if (!IsValidOutputName(name, &why)) throw ParseError{"manifest.outputs: " + why};
    m->outputs[name] = Record(record, "manifest.outputs." + name);
  }

  const Json& journal = Field(j, "journal", top);
  if (!journal.is_array()) throw ParseError{"manifest.journal is not an array"};
  m->journal.clear();
  for (std::size_t i = 0; i < journal.size(); ++i) {
    const std::string where = "manifest.journal[" + std::to_string(i) + "]";
    if (!journal[i].is_object()) throw ParseError{where + " is not an object"};
    m->journal.push_back({String(journal[i], "time", where), String(journal[i], "event", where),
                          String(journal[i], "detail", where)});
  }
}

}  // namespace

const char* ToString(SessionState state) {
  for (const auto& [s, name] : kStateNames) {
    if (s == state) return name;
  }
  return "unknown";
}

bool SessionStateFromString(std::string_view text, SessionState* state) {
  for (const auto& [s, name] : kStateNames) {
    if (text == name) {
      *state = s;
      return true;
    }
  }
  return false;
}

bool IsActive(SessionState state) {
  return state == SessionState::kCreated || state == SessionState::kCapturing ||
         state == SessionState::kReconstructing;
}

bool IsAllowedTransition(SessionState from, SessionState to) {
  using S = SessionState;
  switch (from) {
    case S::kCreated:
      return to == S::kCapturing || to == S::kReconstructing || to == S::kInterrupted ||
             to == S::kFailed;
    case S::kCapturing:
      return to == S::kReconstructing || to == S::kDone || to == S::kInterrupted ||
             to == S::kFailed;
    case S::kReconstructing:
      return to == S::kDone || to == S::kInterrupted || to == S::kFailed;
    case S::kInterrupted:
      return to == S::kCapturing || to == S::kReconstructing || to == S::kFailed;
    case S::kFailed:
      return to == S::kCapturing || to == S::kReconstructing;
    case S::kDone:
      return false;
  }
  return false;
}

std::string SanitizeObjectName(std::string_view name) {
  std::string out;
  out.reserve(name.size());
  for (const char raw : name) {
    const char c = IsNameChar(raw) ? raw : '_';
    // Collapse runs of '_' and of '.' (so ".." can never appear).
    if ((c == '_' || c == '.') && !out.empty() && out.back() == c) continue;
    out.push_back(c);
  }
  std::size_t start = 0;
  while (start < out.size() && (out[start] == '.' || out[start] == '-' || out[start] == '_')) {
    ++start;
  }
  out.erase(0, start);
  if (out.size() > kMaxObjectBytes) out.resize(kMaxObjectBytes);
  while (!out.empty() && out.back() == '_') out.pop_back();
  return out.empty() ? "object" : out;
}

bool IsValidSessionId(std::string_view id) {
  // "YYYYMMDD-HHMMSS-" then a sanitised name (≤ 64 bytes) and an optional
  // collision suffix "-N" (N ≤ 999: ≤ 4 bytes).
  constexpr std::size_t kPrefix = 16;
  if (id.size() <= kPrefix || id.size() > kPrefix + kMaxObjectBytes + 4) return false;
  for (std::size_t i = 0; i < kPrefix; ++i) {
    const bool dash = i == 8 || i == 15;
    if (dash ? id[i] != '-' : !IsDigit(id[i])) return false;
  }
  const std::string_view rest = id.substr(kPrefix);
  if (!IsAlnum(rest.front())) return false;
  for (std::size_t i = 0; i < rest.size(); ++i) {
    if (!IsNameChar(rest[i])) return false;
    if (i > 0 && rest[i] == '.' && rest[i - 1] == '.') return false;
  }
  return true;
}

bool IsValidOutputName(std::string_view name, std::string* why) {
  const auto fail = [&](const std::string& what) {
    if (why) *why = "output name '" + std::string(name) + "' " + what;
    return false;
  };
  if (name.empty()) return fail("is empty");
  if (name.size() > 200) return fail("is longer than 200 bytes");
  if (name.front() == '/') return fail("is absolute");
  int components = 0;
  std::size_t begin = 0;
  while (begin <= name.size()) {
    std::size_t end = name.find('/', begin);
    if (end == std::string_view::npos) end = name.size();
    const std::string_view part = name.substr(begin, end - begin);
    if (part.empty()) return fail("has an empty component");
    if (part == "." || part == "..") return fail("has a '.' or '..' component");
    if (part.front() == '.' || part.front() == '-')
      return fail("has a component starting with '.' or '-'");
    for (const char c : part) {
      if (!IsNameChar(c)) return fail("has a character outside [A-Za-z0-9._-/]");
    }
    if (++components > 4) return fail("has more than 4 components");
    begin = end + 1;
  }
  if (name == "manifest.json" || name == "calibration.yaml") return fail("is reserved");
  if (name == "views" || name.substr(0, 6) == "views/")
    return fail("is inside the reserved views/");
  return true;
}

std::uint64_t Fnv1a64(std::string_view bytes) {
  std::uint64_t hash = 0xcbf29ce484222325ULL;
  for (const unsigned char c : bytes) {
    hash ^= c;
    hash *= 0x100000001b3ULL;
  }
  return hash;
}

bool ViewRecord::HasCapture() const {
  return files.count(kLeftPng) > 0 && files.count(kRightPng) > 0 && files.count(kMetaJson) > 0;
}

std::vector<int> Manifest::CapturedViews() const {
  std::vector<int> out;
  for (const auto& [index, view] : views) {
    if (view.HasCapture()) out.push_back(index);
  }
  return out;
}

std::string ManifestToJson(const Manifest& m) {
  OrderedJson j;
  j["format"] = "craftscan-session";
  j["format_version"] = m.format_version;
  j["id"] = m.id;
  j["object"] = OrderedJson{{"name", m.object_name}, {"sanitized", m.object}};
  j["job"] = m.job;
  j["params"] = m.params;
  j["state"] = ToString(m.state);
  j["error"] = m.error;
  j["created"] = m.created_utc;
  j["updated"] = m.updated_utc;
  if (m.calibration) {
    OrderedJson c{{"id", m.calibration_id}, {"file", "calibration.yaml"}};
    c.update(RecordJson(*m.calibration));
    j["calibration"] = c;
  } else {
    j["calibration"] = nullptr;
  }
  OrderedJson views = OrderedJson::array();
  for (const auto& [index, v] : m.views) {
    OrderedJson files = OrderedJson::object();
    // Fixed order: the order the files are written in.
    for (const char* name :
         {kLeftPng, kRightPng, kMetaJson, kTexturePng, kDisparityPfm, kCloudPly}) {
      const auto it = v.files.find(name);
      if (it != v.files.end()) files[name] = RecordJson(it->second);
    }
    views.push_back(OrderedJson{{"index", index},
                                {"angle_deg", v.angle_deg},
                                {"captured", v.captured_utc},
                                {"files", files}});
  }
  j["views"] = views;
  OrderedJson outputs = OrderedJson::object();
  for (const auto& [name, record] : m.outputs) outputs[name] = RecordJson(record);
  j["outputs"] = outputs;
  OrderedJson journal = OrderedJson::array();
  for (const auto& e : m.journal) {
    journal.push_back(OrderedJson{{"time", e.time_utc}, {"event", e.event}, {"detail", e.detail}});
  }
  j["journal"] = journal;
  // Replace invalid UTF-8 (an operator's object name may have any bytes)
  // rather than throw.
  return j.dump(2, ' ', false, OrderedJson::error_handler_t::replace) + "\n";
}

bool ManifestFromJson(std::string_view text, Manifest* manifest, std::string* error) {
  const Json j = Json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded()) {
    if (error) *error = "manifest is not valid JSON";
    return false;
  }
  try {
    Manifest m;
    ParseManifest(j, &m);
    *manifest = std::move(m);
    return true;
  } catch (const ParseError& e) {
    if (error) *error = e.what;
  } catch (const std::exception& e) {  // json type errors the checks above missed
    if (error) *error = std::string("manifest: ") + e.what();
  }
  return false;
}

}  // namespace craftscan::daemon
