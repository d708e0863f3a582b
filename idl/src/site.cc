// The site's topics (site.h).
#include "craftscan/dds/site.h"

#include <string>

namespace craftscan::dds {
namespace {

TopicQos SiteQos(std::string_view site, int32_t depth, bool transient_local) {
  TopicQos qos;
  qos.reliable = true;
  qos.history_depth = depth;
  qos.transient_local = transient_local;
  qos.partition = std::string(site);
  return qos;
}

}  // namespace

bool IsValidSiteId(std::string_view site, std::string* why) {
  auto fail = [&](const std::string& message) {
    if (why) *why = "site '" + std::string(site) + "': " + message;
    return false;
  };
  if (site.empty()) return fail("is empty");
  if (site.size() > 64) return fail("longer than 64 characters");
  for (char c : site) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                    c == '_' || c == '-';
    if (!ok) return fail("only letters, digits, '_' and '-' are allowed");
  }
  return true;
}

bool IsValidWorkerId(std::string_view worker, std::string* why) {
  std::string station_why;
  if (IsValidStationId(worker, &station_why)) return true;
  if (why)
    *why = "worker id '" + std::string(worker) + "'" + station_why.substr(station_why.find(':'));
  return false;
}

TopicSpec<msg::SiteStation> SiteStationTopic(std::string_view site) {
  TopicQos qos = SiteQos(site, 1, true);
  qos.liveliness_lease_ms = kStationLeaseMs;
  qos.autodispose = false;
  return {"craftscan/site/station", qos};
}
TopicSpec<msg::WorkerStatus> WorkerStatusTopic(std::string_view site) {
  TopicQos qos = SiteQos(site, 1, true);
  qos.liveliness_lease_ms = kWorkerLeaseMs;
  qos.autodispose = false;
  return {"craftscan/site/worker", qos};
}
TopicSpec<msg::JobOffer> JobOfferTopic(std::string_view site) {
  return {"craftscan/site/job", SiteQos(site, 1, true)};
}
TopicSpec<msg::JobClaim> JobClaimTopic(std::string_view site) {
  return {"craftscan/site/claim", SiteQos(site, 16, false)};
}
TopicSpec<msg::JobResult> JobResultTopic(std::string_view site) {
  return {"craftscan/site/result", SiteQos(site, kFileTopicDepth, false)};
}

}  // namespace craftscan::dds
