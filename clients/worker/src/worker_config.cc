#include "worker_config.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <functional>
#include <set>
#include <string_view>
#include <utility>

#include "craftscan/daemon/config.h"
#include "craftscan/daemon/yaml_document.h"
#include "craftscan/dds/participant.h"
#include "craftscan/dds/site.h"

namespace craftscan::worker {
namespace {

using daemon::AtYamlLine;

constexpr std::size_t kMaxTokenBytes = 128;  // what a Command carries (get)
constexpr std::string_view kEnvironmentPrefix = "CRAFTSCAN_WORKER_";

bool Fail(std::string* error, std::string message) {
  if (error) *error = std::move(message);
  return false;
}

// "'text'", or "nothing" for empty text: the end of "…, got X" messages.
std::string Got(std::string_view text) {
  return text.empty() ? "nothing" : "'" + std::string(text) + "'";
}

// One scalar key of the file: its path, how its text is read into the
// config (with the range check) and written back for the dump.
struct Field {
  std::string path;
  bool quoted = false;  // a string in the dump
  std::function<bool(std::string_view text, WorkerConfig& config, std::string* what)> set;
  std::function<std::string(const WorkerConfig& config)> get;
};

// A string whose values `valid` accepts (*what says why not).
// An integer key in 1..max.
Field IntField(std::string path, int WorkerConfig::*member, int max) {
  Field f;
  f.path = std::move(path);
  f.set = [member, max](std::string_view text, WorkerConfig& c, std::string* what) {
    long long v = 0;
    if (!daemon::ParseConfigInteger(text, &v) || v < 1 || v > max) {
      *what = "must be an integer in 1.." + std::to_string(max) + ", got " + Got(text);
      return false;
    }
    c.*member = static_cast<int>(v);
    return true;
  };
  f.get = [member](const WorkerConfig& c) { return std::to_string(c.*member); };
  return f;
}

Field StringField(std::string path, std::string WorkerConfig::*member,
                  std::function<bool(std::string_view, std::string*)> valid) {
  Field f;
  f.path = std::move(path);
  f.quoted = true;
  f.set = [=](std::string_view text, WorkerConfig& c, std::string* what) {
    if (!valid(text, what)) return false;
    c.*member = std::string(text);
    return true;
  };
  f.get = [=](const WorkerConfig& c) { return c.*member; };
  return f;
}

bool AbsolutePath(std::string_view text, std::string* what) {
  if (!text.empty() && text.front() == '/') return true;
  *what = "must be an absolute path, got " + Got(text);
  return false;
}

constexpr std::array<std::string_view, 4> kLogLevels = {"debug", "info", "warning", "error"};

// Every field in schema order (the dump's order; sections stay together).
const std::vector<Field>& Fields() {
  static const std::vector<Field> fields = [] {
    std::vector<Field> f;
    f.push_back(StringField("worker", &WorkerConfig::worker, [](std::string_view text, auto* what) {
      std::string why;
      if (dds::IsValidWorkerId(text, &why)) return true;
      *what = why + " (a letter, then letters, digits and '_', at most 64)";
      return false;
    }));
    f.push_back(StringField("site", &WorkerConfig::site, [](std::string_view text, auto* what) {
      if (dds::IsValidSiteId(text, nullptr)) return true;
      *what = "must be 1 to 64 characters of A-Z, a-z, 0-9, _, - (the stations' site), got " +
              Got(text);
      return false;
    }));
    Field level;
    level.path = "log_level";
    level.set = [](std::string_view text, WorkerConfig& c, std::string* what) {
      for (std::size_t i = 0; i < kLogLevels.size(); ++i) {
        if (text == kLogLevels[i]) {
          c.log_level = static_cast<WorkerLogLevel>(i);
          return true;
        }
      }
      *what = "must be one of debug, info, warning, error; got " + Got(text);
      return false;
    };
    level.get = [](const WorkerConfig& c) {
      return std::string(kLogLevels[static_cast<std::size_t>(c.log_level)]);
    };
    f.push_back(level);
    Field domain;
    domain.path = "dds.domain";
    domain.set = [](std::string_view text, WorkerConfig& c, std::string* what) {
      long long v = 0;
      if (!daemon::ParseConfigInteger(text, &v) || v < 0 || v > dds::kMaxDomainId) {
        *what =
            "must be an integer in 0.." + std::to_string(dds::kMaxDomainId) + ", got " + Got(text);
        return false;
      }
      c.dds.domain = static_cast<uint32_t>(v);
      return true;
    };
    domain.get = [](const WorkerConfig& c) { return std::to_string(c.dds.domain); };
    f.push_back(domain);
    Field dds_file;
    dds_file.path = "dds.config_file";
    dds_file.quoted = true;
    dds_file.set = [](std::string_view text, WorkerConfig& c, std::string* what) {
      if (!text.empty() && !AbsolutePath(text, what)) {
        *what = "must be an absolute path or \"\", got " + Got(text);
        return false;
      }
      c.dds.config_file = std::string(text);
      return true;
    };
    dds_file.get = [](const WorkerConfig& c) { return c.dds.config_file; };
    f.push_back(dds_file);
    Field token;
    token.path = "auth.token_file";
    token.quoted = true;
    token.set = [](std::string_view text, WorkerConfig& c, std::string* what) {
      if (!AbsolutePath(text, what)) return false;
      c.auth.token_file = std::string(text);
      return true;
    };
    token.get = [](const WorkerConfig& c) { return c.auth.token_file; };
    f.push_back(token);
    f.push_back(IntField("threads", &WorkerConfig::threads, 256));
    f.push_back(IntField("jobs", &WorkerConfig::jobs, 16));
    f.push_back(StringField("work_dir", &WorkerConfig::work_dir, AbsolutePath));
    Field watchdog;
    watchdog.path = "watchdog.enabled";
    watchdog.set = [](std::string_view text, WorkerConfig& c, std::string* what) {
      if (daemon::ParseConfigBool(text, &c.watchdog.enabled)) return true;
      *what = "must be true or false, got " + Got(text);
      return false;
    };
    watchdog.get = [](const WorkerConfig& c) {
      return std::string(c.watchdog.enabled ? "true" : "false");
    };
    f.push_back(watchdog);
    return f;
  }();
  return fields;
}

const Field* FindField(std::string_view path) {
  for (const Field& f : Fields()) {
    if (f.path == path) return &f;
  }
  return nullptr;
}

std::string SectionOf(std::string_view path) {
  const std::size_t dot = path.rfind('.');
  return dot == std::string_view::npos ? std::string() : std::string(path.substr(0, dot));
}

bool IsSection(std::string_view path) {
  for (const Field& f : Fields()) {
    if (SectionOf(f.path) == path) return true;
  }
  return false;
}

// "known: a, b, c": the keys of `section` ("" for the top level).
std::string KnownKeys(const std::string& section) {
  std::vector<std::string> keys;
  if (section.empty()) keys.push_back("version");
  for (const Field& f : Fields()) {
    std::string key = f.path.substr(section.empty() ? 0 : section.size() + 1);
    if (!section.empty() && SectionOf(f.path) != section) continue;
    key = key.substr(0, key.find('.'));
    if (std::find(keys.begin(), keys.end(), key) == keys.end()) keys.push_back(key);
  }
  std::string text = "known";
  if (!section.empty()) text += " in " + section;
  for (std::size_t i = 0; i < keys.size(); ++i) text += (i == 0 ? ": " : ", ") + keys[i];
  return text;
}

std::string EnvironmentVariable(std::string_view path) {
  std::string name(kEnvironmentPrefix);
  for (char ch : path) {
    name += ch == '.' ? '_' : static_cast<char>(ch >= 'a' && ch <= 'z' ? ch - 'a' + 'A' : ch);
  }
  return name;
}

class YamlReader {
 public:
  explicit YamlReader(WorkerConfig* config) : config_(config) {}

  bool ReadRoot(const YAML::Node& root, std::string* error) {
    return daemon::CheckConfigRoot(root, kWorkerConfigVersion, "craftscan-worker", error) &&
           ReadMap(root, "", error);
  }

 private:
  bool ReadMap(const YAML::Node& map, const std::string& section, std::string* error) {
    std::set<std::string> keys;
    for (const auto& entry : map) {
      const YAML::Node& key = entry.first;
      const YAML::Node& value = entry.second;
      if (!key.IsScalar()) {
        return Fail(error, (section.empty() ? "configuration" : section) +
                               ": keys must be plain names" + AtYamlLine(key));
      }
      const std::string path = section.empty() ? key.Scalar() : section + "." + key.Scalar();
      if (!keys.insert(key.Scalar()).second) {
        return Fail(error, path + ": given more than once" + AtYamlLine(key));
      }
      if (path == "version") continue;  // CheckConfigRoot
      if (const Field* field = FindField(path)) {
        if (!value.IsScalar() && !value.IsNull()) {
          return Fail(error, path + ": must be a single value, not a " +
                                 (value.IsMap() ? "mapping" : "list") + AtYamlLine(value));
        }
        std::string what;
        if (!field->set(value.IsScalar() ? value.Scalar() : "", *config_, &what)) {
          // An empty value's mark is where the next token starts: name the key's line.
          return Fail(error, path + ": " + what + AtYamlLine(value.IsNull() ? key : value));
        }
      } else if (IsSection(path)) {
        if (value.IsNull()) continue;  // "dds:" with nothing under it
        if (!value.IsMap()) {
          return Fail(error, path + ": must be a mapping of keys (" + KnownKeys(path) + ")" +
                                 AtYamlLine(value));
        }
        if (!ReadMap(value, path, error)) return false;
      } else {
        return Fail(error, path + ": unknown key (" + KnownKeys(section) + ")" + AtYamlLine(key));
      }
    }
    return true;
  }

  WorkerConfig* config_;
};

bool ApplyEnvironment(const std::map<std::string, std::string>& env, WorkerConfig* config,
                      std::string* error) {
  for (const Field& field : Fields()) {
    const std::string variable = EnvironmentVariable(field.path);
    const auto it = env.find(variable);
    if (it == env.end()) continue;
    std::string what;
    if (!field.set(it->second, *config, &what)) {
      return Fail(error, variable + ": " + field.path + ": " + what);
    }
  }
  return true;
}

}  // namespace

std::string WorkerIdForHost(const std::string& host_name) {
  std::string id = "worker_" + host_name;
  for (char& ch : id) {
    const bool ok = (ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') ||
                    (ch >= '0' && ch <= '9') || ch == '_';
    if (!ok) ch = '_';
  }
  if (id.size() > 64) id.resize(64);
  return id;
}

std::string DefaultWorkerId() {
  std::array<char, 256> name{};
  if (::gethostname(name.data(), name.size() - 1) != 0) return WorkerIdForHost("");
  return WorkerIdForHost(name.data());
}

bool WorkerConfig::IsValid(std::string* why) const {
  // Each field's value read back through its parser: one rule per field.
  for (const Field& field : Fields()) {
    WorkerConfig scratch = *this;
    std::string what;
    if (!field.set(field.get(*this), scratch, &what)) return Fail(why, field.path + ": " + what);
  }
  return true;
}

bool ParseWorkerConfig(const std::string& yaml_text, const std::map<std::string, std::string>& env,
                       WorkerConfig* config, std::string* error) {
  WorkerConfig parsed;
  YAML::Node root;
  if (!daemon::LoadOneYamlDocument(yaml_text, &root, error)) return false;
  try {
    YamlReader reader(&parsed);
    if (!reader.ReadRoot(root, error)) return false;
  } catch (const YAML::Exception& e) {
    return Fail(error, "YAML error: " + e.msg);
  }
  if (!ApplyEnvironment(env, &parsed, error)) return false;
  if (!parsed.IsValid(error)) return false;
  *config = std::move(parsed);
  return true;
}

bool LoadWorkerConfig(const std::string& path, WorkerConfig* config, std::string* error) {
  std::string text;
  if (!daemon::ReadConfigText(path, &text, error)) return false;
  std::string why;
  if (!ParseWorkerConfig(text, daemon::CraftscanEnvironment(), config, &why)) {
    return Fail(error, path + ": " + why);
  }
  return true;
}

std::string DumpWorkerConfig(const WorkerConfig& config) {
  YAML::Emitter out;
  out << YAML::BeginMap << YAML::Key << "version" << YAML::Value << kWorkerConfigVersion;
  std::string open;  // the section being written, "" at the top level
  for (const Field& field : Fields()) {
    const std::string section = SectionOf(field.path);
    if (section != open) {
      if (!open.empty()) out << YAML::EndMap;
      if (!section.empty()) out << YAML::Key << section << YAML::Value << YAML::BeginMap;
      open = section;
    }
    out << YAML::Key << field.path.substr(section.empty() ? 0 : section.size() + 1) << YAML::Value;
    if (field.quoted) {
      out << YAML::DoubleQuoted << field.get(config);
    } else {
      out << field.get(config);
    }
  }
  if (!open.empty()) out << YAML::EndMap;
  out << YAML::EndMap;
  return std::string(out.c_str()) + "\n";
}

std::vector<std::string> WorkerEnvironmentVariables() {
  std::vector<std::string> names;
  for (const Field& field : Fields()) names.push_back(EnvironmentVariable(field.path));
  return names;
}

bool ReadWorkerToken(const std::string& path, std::string* token, std::string* error) {
  const std::string where = "auth.token_file: " + path + ": ";
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOCTTY);
  if (fd < 0) return Fail(error, where + "cannot open: " + std::strerror(errno));
  struct stat st {};
  std::string text;
  std::string problem;
  if (::fstat(fd, &st) != 0) {
    problem = std::string("cannot stat: ") + std::strerror(errno);
  } else if (!S_ISREG(st.st_mode)) {
    problem = "not a regular file";
  } else if ((st.st_mode & 077) != 0) {
    std::array<char, 8> mode{};
    std::snprintf(mode.data(), mode.size(), "%04o", static_cast<unsigned>(st.st_mode & 07777));
    problem = std::string("mode ") + mode.data() +
              " lets group or others read the token; make it readable by the worker's user "
              "only (chmod 0600, owner craftscan)";
  } else {
    // The first line is all that is used: read a little more than a token.
    std::array<char, kMaxTokenBytes + 8> buffer{};
    ssize_t n = 0;
    while (text.size() < buffer.size() && (n = ::read(fd, buffer.data(), buffer.size())) != 0) {
      if (n < 0) {
        if (errno == EINTR) continue;
        problem = std::string("read error: ") + std::strerror(errno);
        break;
      }
      text.append(buffer.data(), static_cast<std::size_t>(n));
      if (text.find('\n') != std::string::npos) break;
    }
  }
  ::close(fd);
  if (!problem.empty()) return Fail(error, where + problem);
  text = text.substr(0, text.find('\n'));
  while (!text.empty() && (text.back() == '\r' || text.back() == ' ' || text.back() == '\t')) {
    text.pop_back();
  }
  if (text.empty()) {
    return Fail(error, where + "the first line is empty; put the worker's token there");
  }
  if (text.size() > kMaxTokenBytes) {
    return Fail(error,
                where + "the token is longer than " + std::to_string(kMaxTokenBytes) + " bytes");
  }
  for (char ch : text) {
    if (static_cast<unsigned char>(ch) < ' ' || ch == 0x7f) {
      return Fail(error, where + "the token has a control character");
    }
  }
  *token = std::move(text);
  return true;
}

bool MakeWorkerOptions(const WorkerConfig& config, WorkerOptions* options, std::string* error) {
  WorkerOptions made;
  made.worker_id = config.worker;
  made.site = config.site;
  made.domain = config.dds.domain;
  if (!config.dds.config_file.empty()) {
    // Cyclone would only say it cannot parse its configuration.
    if (::access(config.dds.config_file.c_str(), R_OK) != 0) {
      return Fail(error, "dds.config_file: " + config.dds.config_file +
                             ": cannot read: " + std::strerror(errno));
    }
    made.dds_config = dds::ConfigFileUri(config.dds.config_file);
  }
  if (!ReadWorkerToken(config.auth.token_file, &made.token, error)) return false;
  made.threads = config.threads;
  made.jobs = config.jobs;
  made.work_dir = config.work_dir;
  std::string why;
  if (!made.IsValid(&why)) return Fail(error, why);
  *options = std::move(made);
  return true;
}

}  // namespace craftscan::worker
