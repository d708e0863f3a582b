// craftscan-web's configuration (YAML, `version: 1`, like craftscand's):
//
//   version: 1
//   listen: 127.0.0.1:8080        # host:port; localhost by default
//   stations: [station1]          # the stations this console serves (≥ 1)
//   domain_id: 0
//   dds_config: ""                # as craftscanctl's --dds-config
//   tls: {certificate: /etc/craftscan/web.crt, private_key: /etc/craftscan/web.key}
//   assets_dir: ""                # "" = next to the binary, else /usr/share/craftscan/web
//   cache_dir: /var/cache/craftscan-web
//   session_idle_minutes: 60      # a console session ends after this long unused
//   max_body_bytes: 65536
//   command_timeout_ms: 10000
//
// Every key is optional except `version`. An unknown key, a wrong type or an
// out-of-range value is an error naming the key and its line.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace craftscan::web {

inline constexpr int kWebConfigVersion = 1;

struct WebConfig {
  std::string listen_host = "127.0.0.1";
  std::uint16_t listen_port = 8080;
  std::vector<std::string> stations = {"station1"};
  std::uint32_t domain_id = 0;
  std::string dds_config;
  std::string tls_certificate, tls_private_key;  // both or neither
  std::string assets_dir;
  std::string cache_dir = "/var/cache/craftscan-web";
  int session_idle_minutes = 60;
  std::size_t max_body_bytes = 65536;
  int command_timeout_ms = 10000;

  bool tls() const { return !tls_certificate.empty(); }
  // False with *why naming the key.
  bool IsValid(std::string* why) const;
};

// Parses YAML text. False with *error naming the key (and line).
bool ParseWebConfig(const std::string& yaml_text, WebConfig* config, std::string* error);
// Reads and parses a file; the error names the file.
bool LoadWebConfig(const std::string& path, WebConfig* config, std::string* error);

// "host:port" → parts. Host may be an IPv4 address, a name or [IPv6].
bool ParseListen(const std::string& text, std::string* host, std::uint16_t* port, std::string* why);

}  // namespace craftscan::web
