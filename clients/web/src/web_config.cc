#include "craftscan/web/web_config.h"

#include <yaml-cpp/yaml.h>

#include <fstream>
#include <limits>
#include <set>
#include <sstream>

namespace craftscan::web {
namespace {

bool Fail(std::string* error, std::string message) {
  if (error) *error = std::move(message);
  return false;
}

std::string AtLine(const YAML::Node& node) {
  const YAML::Mark mark = node.Mark();
  return mark.line >= 0 ? " (line " + std::to_string(mark.line + 1) + ")" : "";
}

bool ValidStationId(const std::string& id) {
  if (id.empty() || id.size() > 64) return false;
  for (char c : id) {
    const bool ok =
        (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_';
    if (!ok) return false;
  }
  return true;
}

bool ReadString(const YAML::Node& value, const std::string& key, std::string* out,
                std::string* error) {
  if (!value.IsScalar()) return Fail(error, key + ": must be a string" + AtLine(value));
  *out = value.Scalar();
  return true;
}

bool ReadInt(const YAML::Node& value, const std::string& key, long long min, long long max,
             long long* out, std::string* error) {
  const std::string range = " in " + std::to_string(min) + ".." + std::to_string(max);
  if (!value.IsScalar()) return Fail(error, key + ": must be an integer" + range + AtLine(value));
  std::size_t used = 0;
  long long v = 0;
  try {
    v = std::stoll(value.Scalar(), &used, 10);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != value.Scalar().size() || v < min || v > max) {
    return Fail(error, key + ": must be an integer" + range + ", got '" + value.Scalar() + "'" +
                           AtLine(value));
  }
  *out = v;
  return true;
}

}  // namespace

bool ParseListen(const std::string& text, std::string* host, std::uint16_t* port,
                 std::string* why) {
  const std::size_t colon = text.rfind(':');
  if (colon == std::string::npos || colon == 0 || colon + 1 == text.size()) {
    return Fail(why, "must be host:port (e.g. 127.0.0.1:8080), got '" + text + "'");
  }
  std::string h = text.substr(0, colon);
  if (h.front() == '[') {
    if (h.back() != ']') return Fail(why, "an IPv6 host must be in brackets: '" + text + "'");
    h = h.substr(1, h.size() - 2);
  }
  long long p = 0;
  std::size_t used = 0;
  try {
    p = std::stoll(text.substr(colon + 1), &used, 10);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != text.size() - colon - 1 || p < 0 || p > 65535) {
    return Fail(why, "the port must be 0..65535, got '" + text.substr(colon + 1) + "'");
  }
  *host = h;
  *port = static_cast<std::uint16_t>(p);
  return true;
}

bool WebConfig::IsValid(std::string* why) const {
  if (listen_host.empty()) return Fail(why, "listen: the host is empty");
  if (stations.empty()) return Fail(why, "stations: list at least one station id");
  std::set<std::string> seen;
  for (const std::string& s : stations) {
    if (!ValidStationId(s)) {
      return Fail(why, "stations: '" + s + "' is not a station id (1..64 of A-Z a-z 0-9 _)");
    }
    if (!seen.insert(s).second) return Fail(why, "stations: '" + s + "' is listed twice");
  }
  if (domain_id > 230) return Fail(why, "domain_id: must be 0..230");
  if (tls_certificate.empty() != tls_private_key.empty()) {
    return Fail(why, "tls: give both certificate and private_key, or neither");
  }
  if (cache_dir.empty()) return Fail(why, "cache_dir: must not be empty");
  if (session_idle_minutes < 1 || session_idle_minutes > 7 * 24 * 60) {
    return Fail(why, "session_idle_minutes: must be 1..10080");
  }
  if (max_body_bytes < 1024 || max_body_bytes > (std::size_t{16} << 20)) {
    return Fail(why, "max_body_bytes: must be 1024..16777216");
  }
  if (command_timeout_ms < 100 || command_timeout_ms > 600000) {
    return Fail(why, "command_timeout_ms: must be 100..600000");
  }
  return true;
}

bool ParseWebConfig(const std::string& yaml_text, WebConfig* config, std::string* error) {
  YAML::Node root;
  try {
    root = YAML::Load(yaml_text);
  } catch (const YAML::Exception& e) {
    return Fail(error, std::string("not valid YAML: ") + e.what());
  }
  const std::string hint =
      "expected a mapping starting with 'version: " + std::to_string(kWebConfigVersion) + "'";
  if (!root || root.IsNull()) return Fail(error, "empty configuration; " + hint);
  if (!root.IsMap()) return Fail(error, "the configuration must be a mapping; " + hint);
  if (!root["version"]) {
    return Fail(error,
                "version: missing; add 'version: " + std::to_string(kWebConfigVersion) + "'");
  }
  WebConfig c;
  for (const auto& entry : root) {
    if (!entry.first.IsScalar()) return Fail(error, "a key must be a string" + AtLine(entry.first));
    const std::string key = entry.first.Scalar();
    const YAML::Node& value = entry.second;
    long long n = 0;
    if (key == "version") {
      if (!ReadInt(value, key, 0, std::numeric_limits<int>::max(), &n, error)) return false;
      if (n != kWebConfigVersion) {
        return Fail(error, "version: " + value.Scalar() + " is not supported; this craftscan-web " +
                               "reads version " + std::to_string(kWebConfigVersion) +
                               AtLine(value));
      }
    } else if (key == "listen") {
      std::string text, why;
      if (!ReadString(value, key, &text, error)) return false;
      if (!ParseListen(text, &c.listen_host, &c.listen_port, &why)) {
        return Fail(error, "listen: " + why + AtLine(value));
      }
    } else if (key == "stations") {
      if (!value.IsSequence()) {
        return Fail(error, "stations: must be a list of station ids" + AtLine(value));
      }
      c.stations.clear();
      for (const auto& item : value) {
        std::string id;
        if (!ReadString(item, "stations", &id, error)) return false;
        c.stations.push_back(id);
      }
    } else if (key == "domain_id") {
      if (!ReadInt(value, key, 0, 230, &n, error)) return false;
      c.domain_id = static_cast<std::uint32_t>(n);
    } else if (key == "dds_config") {
      if (!ReadString(value, key, &c.dds_config, error)) return false;
    } else if (key == "tls") {
      if (!value.IsMap()) {
        return Fail(error, "tls: must be a mapping {certificate, private_key}" + AtLine(value));
      }
      for (const auto& t : value) {
        const std::string sub = t.first.IsScalar() ? t.first.Scalar() : "";
        if (sub == "certificate") {
          if (!ReadString(t.second, "tls.certificate", &c.tls_certificate, error)) return false;
        } else if (sub == "private_key") {
          if (!ReadString(t.second, "tls.private_key", &c.tls_private_key, error)) return false;
        } else {
          return Fail(error, "tls." + sub + ": unknown key (known: certificate, private_key)" +
                                 AtLine(t.first));
        }
      }
    } else if (key == "assets_dir") {
      if (!ReadString(value, key, &c.assets_dir, error)) return false;
    } else if (key == "cache_dir") {
      if (!ReadString(value, key, &c.cache_dir, error)) return false;
    } else if (key == "session_idle_minutes") {
      if (!ReadInt(value, key, 1, 7 * 24 * 60, &n, error)) return false;
      c.session_idle_minutes = static_cast<int>(n);
    } else if (key == "max_body_bytes") {
      if (!ReadInt(value, key, 1024, 16 << 20, &n, error)) return false;
      c.max_body_bytes = static_cast<std::size_t>(n);
    } else if (key == "command_timeout_ms") {
      if (!ReadInt(value, key, 100, 600000, &n, error)) return false;
      c.command_timeout_ms = static_cast<int>(n);
    } else {
      return Fail(error, key +
                             ": unknown key (known: version, listen, stations, domain_id, "
                             "dds_config, tls, assets_dir, cache_dir, session_idle_minutes, "
                             "max_body_bytes, command_timeout_ms)" +
                             AtLine(entry.first));
    }
  }
  std::string why;
  if (!c.IsValid(&why)) return Fail(error, why);
  *config = std::move(c);
  return true;
}

bool LoadWebConfig(const std::string& path, WebConfig* config, std::string* error) {
  std::ifstream in(path);
  if (!in) return Fail(error, path + ": cannot open the configuration file");
  std::ostringstream text;
  text << in.rdbuf();
  std::string why;
  if (!ParseWebConfig(text.str(), config, &why)) return Fail(error, path + ": " + why);
  return true;
}

}  // namespace craftscan::web
