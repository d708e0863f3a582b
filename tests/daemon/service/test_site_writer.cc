// The daemon's SiteWriter (daemon/service/src/dds_bridge.h) against a reader
// of the site's station topic on loopback DDS: what Publish writes, that
// SetRemoteJob is written at once (and only when it changes), the renewal
// clock of its liveliness lease, and Dispose.
#include <gtest/gtest.h>

#include <chrono>
#include <string>
#include <thread>

#include "craftscan/dds/endpoint.h"
#include "craftscan/dds/site.h"
#include "dds_bridge.h"
#include "dds_test_util.h"

namespace craftscan::daemon {
namespace {

using std::chrono::milliseconds;

class SiteWriterTest : public ::testing::Test {
 protected:
  void SetUp() override {
    participant_ = testing::MakeTestParticipant();
    ASSERT_NE(participant_, nullptr);
    site_ = testing::UniqueStation("site");
    std::string error;
    reader_ = dds::Reader<dds::msg::SiteStation>::Create(participant_, dds::SiteStationTopic(site_),
                                                         &error);
    ASSERT_NE(reader_, nullptr) << error;
    ASSERT_TRUE(writer_.Create(participant_, site_, "st1", "auto", &error)) << error;
  }

  // The next sample within `wait`; false on timeout.
  bool Next(dds::SampleState* state, milliseconds wait = milliseconds(3000)) {
    std::string error;
    return reader_->TakeWithInfo(wait, &sample_, state, &error) == dds::TakeStatus::kOk;
  }

  std::shared_ptr<dds::Participant> participant_;
  std::string site_;
  std::unique_ptr<dds::Reader<dds::msg::SiteStation>> reader_;
  dds::Sample<dds::msg::SiteStation> sample_;
  SiteWriter writer_;
};

TEST_F(SiteWriterTest, PublishesTheStatusAndTheRemoteJobAtOnceThenDisposes) {
  StationStatusFields status;
  status.station = "st1";
  status.state = StationState::kBusy;
  status.job.id = "job-3";
  status.job.verb = "scan";
  status.job.state = JobState::kRunning;
  status.job.progress = 0.5;
  writer_.Publish(status);
  EXPECT_FALSE(writer_.RenewalDue(SiteWriter::Clock::now()));
  EXPECT_TRUE(writer_.RenewalDue(SiteWriter::Clock::now() + SiteWriter::kRenewInterval));
  EXPECT_LE(SiteWriter::kRenewInterval.count(), dds::kStationLeaseMs / 4);

  dds::SampleState state;
  ASSERT_TRUE(Next(&state));
  ASSERT_TRUE(state.valid_data);
  EXPECT_EQ(state.instance, dds::InstanceState::kAlive);
  EXPECT_STREQ(sample_->station, "st1");
  EXPECT_STREQ(sample_->state, "busy");
  EXPECT_STREQ(sample_->job_id, "job-3");
  EXPECT_STREQ(sample_->job_verb, "scan");
  EXPECT_STREQ(sample_->job_state, "running");
  EXPECT_DOUBLE_EQ(sample_->progress, 0.5);
  EXPECT_STREQ(sample_->reconstruction, "auto");
  EXPECT_STREQ(sample_->remote_job, "");
  EXPECT_STREQ(sample_->remote_worker, "");
  EXPECT_GE(sample_->load, 0.0);
  EXPECT_GT(sample_->stamp_ns, 0);

  // The job protocol's setter is written at once, from another thread,
  // with the status fields kept.
  std::thread([&] { writer_.SetRemoteJob("st1/20260101-000000-box/1", "w1"); }).join();
  ASSERT_TRUE(Next(&state, milliseconds(2000)));
  EXPECT_STREQ(sample_->remote_job, "st1/20260101-000000-box/1");
  EXPECT_STREQ(sample_->remote_worker, "w1");
  EXPECT_STREQ(sample_->job_id, "job-3");
  EXPECT_STREQ(sample_->state, "busy");
  // The same again: nothing to write.
  writer_.SetRemoteJob("st1/20260101-000000-box/1", "w1");
  EXPECT_FALSE(Next(&state, milliseconds(300)));
  // Cleared; kept by the next status.
  writer_.SetRemoteJob("", "");
  ASSERT_TRUE(Next(&state, milliseconds(2000)));
  EXPECT_STREQ(sample_->remote_job, "");
  status.state = StationState::kIdle;
  writer_.Publish(status);
  ASSERT_TRUE(Next(&state));
  EXPECT_STREQ(sample_->state, "idle");
  EXPECT_STREQ(sample_->remote_worker, "");

  // Dispose: readers see the instance disposed; nothing is written after.
  writer_.Dispose();
  ASSERT_TRUE(Next(&state));
  EXPECT_FALSE(state.valid_data);
  EXPECT_EQ(state.instance, dds::InstanceState::kDisposed);
  writer_.Publish(status);
  writer_.SetRemoteJob("x", "y");
  EXPECT_FALSE(Next(&state, milliseconds(300)));
}

}  // namespace
}  // namespace craftscan::daemon
