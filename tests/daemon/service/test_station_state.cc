// The station's state (daemon.h): the strings StationStatus carries, which
// clients compare, and the state each combination of facts gives.
#include <gtest/gtest.h>

#include "craftscan/daemon/daemon.h"

namespace craftscan::daemon {
namespace {

TEST(StationState, NamesAreTheOnesClientsCompare) {
  EXPECT_EQ(ToString(StationState::kStarting), "starting");
  EXPECT_EQ(ToString(StationState::kIdle), "idle");
  EXPECT_EQ(ToString(StationState::kBusy), "busy");
  EXPECT_EQ(ToString(StationState::kDegraded), "degraded");
  EXPECT_EQ(ToString(StationState::kError), "error");
  EXPECT_EQ(ToString(StationState::kStopping), "stopping");
}

StationFacts Serving() {
  StationFacts facts;
  facts.devices_tried = facts.devices_open = facts.store_open = true;
  return facts;
}

TEST(StationState, FollowsDevicesJobsAndStorage) {
  StationFacts facts;
  EXPECT_EQ(StationStateFrom(facts), StationState::kStarting);
  facts = Serving();
  EXPECT_EQ(StationStateFrom(facts), StationState::kIdle);
  facts.job_running = true;
  EXPECT_EQ(StationStateFrom(facts), StationState::kBusy);
  facts = Serving();
  facts.store_open = false;
  EXPECT_EQ(StationStateFrom(facts), StationState::kDegraded);
  facts.devices_open = false;  // no devices outranks no storage
  EXPECT_EQ(StationStateFrom(facts), StationState::kError);
  facts.stopping = true;
  EXPECT_EQ(StationStateFrom(facts), StationState::kStopping);
}

// A job reopens the devices (the sim's calibration scenes): while it runs
// the station is busy even in the moment they are closed.
TEST(StationState, BusyWhileAJobReopensTheDevices) {
  StationFacts facts = Serving();
  facts.job_running = true;
  facts.devices_open = false;
  EXPECT_EQ(StationStateFrom(facts), StationState::kBusy);
}

// The bug this enum's refactor found: the state was recomputed only while
// the devices were open, so a job that ended with them closed (a scene
// switch whose reopen failed) left the station "busy" with no job running
// until a device retry succeeded. It is "error", as at a failed start.
TEST(StationState, AJobEndingWithTheDevicesClosedIsAnErrorNotBusy) {
  StationFacts facts = Serving();
  facts.devices_open = false;
  facts.job_running = false;
  EXPECT_EQ(StationStateFrom(facts), StationState::kError);
}

}  // namespace
}  // namespace craftscan::daemon
