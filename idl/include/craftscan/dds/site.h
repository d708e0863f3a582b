// The site's topics (craftscan.idl, "The site"): every station and
// reconstruction worker of one site shares them, in the DDS partition named
// by the site, so sites on one domain stay apart.
//
//   craftscan/site/station  SiteStation   reliable, transient-local, keep-last 1 per station
//   craftscan/site/worker   WorkerStatus  reliable, transient-local, keep-last 1 per worker,
//                                         liveliness manual-by-topic, lease kWorkerLeaseMs
//   craftscan/site/job      JobOffer      reliable, transient-local, keep-last 1 per job
//   craftscan/site/claim    JobClaim      reliable, volatile, keep-last 16
//   craftscan/site/result   JobResult     reliable, volatile, keep-last 64
//
// Which DDS mechanism carries which rule of the job protocol:
//  - a worker that dies or is cut off loses its grant: WorkerStatus's
//    liveliness lease (manual by topic; the worker writes its status every
//    lease/4) lapses and the station's reader sees the worker's instance
//    NOT_ALIVE_NO_WRITERS (a stopped worker disposes it);
//  - a late-starting worker sees open offers: JobOffer is transient-local,
//    keyed by job id, keep-last 1 per instance (the offer's current state);
//  - a job's life: the JobOffer instance is written offered → granted (→
//    offered again after a lost lease) and disposed when the station stored
//    the result or reconstructs locally; a station that died goes
//    NOT_ALIVE_NO_WRITERS at the workers, which drop its jobs;
//  - sites apart: the partition.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>

#include "craftscan/dds/messages.h"
#include "craftscan/dds/topics.h"

namespace craftscan::dds {

namespace msg {
using SiteStation = craftscan_msg_SiteStation;
using WorkerStatus = craftscan_msg_WorkerStatus;
using JobOffer = craftscan_msg_JobOffer;
using JobClaim = craftscan_msg_JobClaim;
using JobResult = craftscan_msg_JobResult;
}  // namespace msg

#define CRAFTSCAN_DDS_SITE_TRAITS(Type)                                        \
  template <>                                                                  \
  struct MessageTraits<Type> {                                                 \
    static const dds_topic_descriptor_t* descriptor() { return &Type##_desc; } \
    static const char* type_name() { return Type##_desc.m_typename; }          \
  }
CRAFTSCAN_DDS_SITE_TRAITS(craftscan_msg_SiteStation);
CRAFTSCAN_DDS_SITE_TRAITS(craftscan_msg_WorkerStatus);
CRAFTSCAN_DDS_SITE_TRAITS(craftscan_msg_JobOffer);
CRAFTSCAN_DDS_SITE_TRAITS(craftscan_msg_JobClaim);
CRAFTSCAN_DDS_SITE_TRAITS(craftscan_msg_JobResult);
#undef CRAFTSCAN_DDS_SITE_TRAITS

// The site every station and worker is on unless configured otherwise.
inline constexpr std::string_view kDefaultSite = "default";
// A worker's liveliness lease (ms): it writes its WorkerStatus at least every
// quarter of it; a station takes a granted job back this long after the
// worker's last sign of life. Not shorter: a station on a small CPU share
// that is matching may take its DDS samples a few seconds late (2 s was
// seen to lapse for a live worker on a 0.3-core station).
inline constexpr int32_t kWorkerLeaseMs = 6000;
// A station's SiteStation writer has the same kind of lease, so the site
// view drops a station that died without disposing its instance.
inline constexpr int32_t kStationLeaseMs = 4000;

// A site name as used for the partition: 1..64 characters of [A-Za-z0-9_-].
// False with *why (may be null) otherwise.
bool IsValidSiteId(std::string_view site, std::string* why);
// A worker id: as a station id (IsValidStationId).
bool IsValidWorkerId(std::string_view worker, std::string* why);

TopicSpec<msg::SiteStation> SiteStationTopic(std::string_view site);
TopicSpec<msg::WorkerStatus> WorkerStatusTopic(std::string_view site);
TopicSpec<msg::JobOffer> JobOfferTopic(std::string_view site);
TopicSpec<msg::JobClaim> JobClaimTopic(std::string_view site);
TopicSpec<msg::JobResult> JobResultTopic(std::string_view site);

}  // namespace craftscan::dds
