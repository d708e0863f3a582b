// StationClient::Fetch against a scripted station on loopback DDS: a
// transfer whose first chunks went by before the station's file writer
// matched the client's reader (discovery runs both ways on its own) is asked
// for again; a `get` the station never saw is sent again under its id; a gap
// in the middle still fails with its reason.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <functional>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "craftscan/client/file_assembler.h"
#include "craftscan/client/station_client.h"
#include "craftscan/dds/endpoint.h"
#include "craftscan/dds/messages.h"
#include "craftscan/dds/topics.h"
#include "dds_test_util.h"
#include "file_util.h"

namespace craftscan::client {
namespace {

using std::chrono::milliseconds;
constexpr milliseconds kTimeout{20000};
constexpr std::size_t kChunk = 4096;

// Answers each `get` with one file sent in kChunk pieces; `skip(n, offset)`
// says whether the n-th get (from 1) leaves out the chunk at `offset`, as a
// writer that had not matched the reader yet, or a lost sample, would.
class ScriptedStation {
 public:
  ScriptedStation(std::string station, std::string payload,
                  std::function<bool(int, std::uint64_t)> skip, int unseen_commands = 0)
      : station_(std::move(station)),
        payload_(std::move(payload)),
        skip_(std::move(skip)),
        unseen_commands_(unseen_commands) {
    participant_ = ::craftscan::testing::MakeTestParticipant();
    std::string error;
    commands_ =
        dds::Reader<dds::msg::Command>::Create(participant_, dds::CommandTopic(station_), &error);
    replies_ =
        dds::Writer<dds::msg::Reply>::Create(participant_, dds::ReplyTopic(station_), &error);
    files_ =
        dds::Writer<dds::msg::SessionFile>::Create(participant_, dds::FileTopic(station_), &error);
    EXPECT_TRUE(commands_ && replies_ && files_) << error;
    if (commands_ && replies_ && files_) thread_ = std::thread([this] { Serve(); });
  }
  ~ScriptedStation() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
  }
  int gets() const { return gets_; }
  // The request id of every command taken, those ignored included.
  std::vector<std::string> ids() const {
    std::lock_guard lock(mutex_);
    return ids_;
  }

 private:
  void Serve() {
    dds::Sample<dds::msg::Command> command;
    std::string error;
    while (!stop_) {
      if (commands_->Take(milliseconds(50), &command, &error) != dds::TakeStatus::kOk) continue;
      if (dds::View(command->verb) != "get") continue;
      const std::string id(dds::View(command->request_id));
      {
        std::lock_guard lock(mutex_);
        ids_.push_back(id);
      }
      // As if its reader had not matched the client's writer yet.
      if (unseen_commands_ > 0) {
        --unseen_commands_;
        continue;
      }
      const int n = ++gets_;
      nlohmann::json file = {
          {"name", "mesh.glb"}, {"size", payload_.size()}, {"fnv1a64", Hex64(Fnv1a64(payload_))}};
      dds::Outgoing<dds::msg::Reply> reply;
      reply.msg().request_id = reply.Keep(id);
      reply.msg().client = reply.Keep(dds::View(command->client));
      reply.msg().code_name = reply.Keep("ok");
      reply.msg().result = reply.Keep(nlohmann::json({{"files", {file}}}).dump());
      ASSERT_TRUE(replies_->Write(reply.msg(), &error)) << error;
      files_->WaitForReaders(1, kTimeout);
      for (std::uint64_t offset = 0; offset < payload_.size(); offset += kChunk) {
        if (skip_(n, offset)) continue;
        const std::size_t size = std::min<std::size_t>(kChunk, payload_.size() - offset);
        dds::Outgoing<dds::msg::SessionFile> out;
        auto& m = out.msg();
        m.request_id = out.Keep(id);
        m.session = out.Keep("20260101-000000-box");
        m.name = out.Keep("mesh.glb");
        m.file_index = 0;
        m.file_count = 1;
        m.total_size = payload_.size();
        m.offset = offset;
        dds::Borrow(&m.data, reinterpret_cast<const std::uint8_t*>(payload_.data()) + offset, size);
        m.last = offset + size == payload_.size();
        ASSERT_TRUE(files_->Write(m, &error)) << error;
      }
    }
  }

  static std::uint64_t Fnv1a64(const std::string& bytes) {
    Fnv1a64Hasher hasher;
    hasher.Update(bytes.data(), bytes.size());
    return hasher.value();
  }

  std::string station_, payload_;
  std::function<bool(int, std::uint64_t)> skip_;
  int unseen_commands_;
  mutable std::mutex mutex_;
  std::vector<std::string> ids_;
  std::shared_ptr<dds::Participant> participant_;
  std::unique_ptr<dds::Reader<dds::msg::Command>> commands_;
  std::unique_ptr<dds::Writer<dds::msg::Reply>> replies_;
  std::unique_ptr<dds::Writer<dds::msg::SessionFile>> files_;
  std::atomic<bool> stop_{false};
  std::atomic<int> gets_{0};
  std::thread thread_;
};

class FetchRetry : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_FALSE(temp_.path().empty());
    out_dir_ = temp_.path();
    for (int i = 0; i < 5 * 4096 + 123; ++i) payload_.push_back(static_cast<char>(i * 7 + i / 13));
  }

  FetchResult Fetch(const std::string& station) {
    ConnectOptions connect;
    connect.station = station;
    connect.domain_id = ::craftscan::testing::ProcessDomainId();
    connect.dds_config = "";  // the station's participant configured the domain
    connect.client_name = "fetch-test";
    std::string error;
    std::unique_ptr<StationClient> client = StationClient::Connect(connect, &error);
    EXPECT_TRUE(client) << error;
    if (!client) return {};
    FetchRequest request;
    request.session = "20260101-000000-box";
    request.files = {"mesh.glb"};
    request.out_dir = out_dir_;
    request.chunk_bytes = kChunk;
    request.timeout = kTimeout;
    return client->Fetch(request);
  }

  std::string ReadOut() const { return ::craftscan::testing::ReadFile(out_dir_ + "/mesh.glb"); }

  ::craftscan::testing::TempDir temp_{"craftscan-fetch"};
  std::string out_dir_, payload_;
};

TEST_F(FetchRetry, ATransferThatStartedBeforeTheReaderMatchedIsAskedForAgain) {
  const std::string station = ::craftscan::testing::UniqueStation("fr");
  // The first get's first two chunks go by unseen.
  ScriptedStation fake(station, payload_,
                       [](int n, std::uint64_t offset) { return n == 1 && offset < 2 * kChunk; });
  const FetchResult got = Fetch(station);
  ASSERT_EQ(got.status, FetchStatus::kOk) << got.message;
  EXPECT_EQ(got.retries, 1);
  EXPECT_EQ(fake.gets(), 2);
  EXPECT_TRUE(ReadOut() == payload_) << "the fetched file differs from the station's";
}

TEST_F(FetchRetry, ATransferOfWhichNoChunkCameIsAskedForAgain) {
  const std::string station = ::craftscan::testing::UniqueStation("fr");
  // Every chunk of the first get goes by unseen (a small model is sent whole
  // before the writer matches the reader).
  ScriptedStation fake(station, payload_, [](int n, std::uint64_t) { return n == 1; });
  const FetchResult got = Fetch(station);
  ASSERT_EQ(got.status, FetchStatus::kOk) << got.message;
  EXPECT_EQ(got.retries, 1);
  EXPECT_EQ(fake.gets(), 2);
  EXPECT_TRUE(ReadOut() == payload_) << "the fetched file differs from the station's";
}

TEST_F(FetchRetry, AGetTheStationNeverSawIsSentAgainUnderItsId) {
  const std::string station = ::craftscan::testing::UniqueStation("fr");
  // The station's command reader misses the first two sends of the get.
  ScriptedStation fake(
      station, payload_, [](int, std::uint64_t) { return false; }, 2);
  const auto start = std::chrono::steady_clock::now();
  const FetchResult got = Fetch(station);
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  ASSERT_EQ(got.status, FetchStatus::kOk) << got.message;
  EXPECT_EQ(got.retries, 0);  // one transfer: the same get, sent again
  EXPECT_EQ(fake.gets(), 1);
  const std::vector<std::string> ids = fake.ids();
  ASSERT_EQ(ids.size(), 3u);
  EXPECT_EQ(ids[0], ids[1]);
  EXPECT_EQ(ids[1], ids[2]);
  // Sent again after 1 s and 2 s more, not after the 20 s timeout.
  EXPECT_LT(seconds, 10.0);
  EXPECT_TRUE(ReadOut() == payload_) << "the fetched file differs from the station's";
}

TEST_F(FetchRetry, AStationThatNeverSendsTheStartFailsAfterThreeGets) {
  const std::string station = ::craftscan::testing::UniqueStation("fr");
  ScriptedStation fake(station, payload_, [](int, std::uint64_t offset) { return offset == 0; });
  const FetchResult got = Fetch(station);
  EXPECT_EQ(got.status, FetchStatus::kTransferFailed);
  EXPECT_NE(got.message.find("chunks were lost"), std::string::npos) << got.message;
  EXPECT_EQ(got.retries, 2);
  EXPECT_EQ(fake.gets(), 3);
  EXPECT_FALSE(std::filesystem::exists(out_dir_ + "/mesh.glb"));
}

TEST_F(FetchRetry, AGapInTheMiddleFailsWithoutAskingAgain) {
  const std::string station = ::craftscan::testing::UniqueStation("fr");
  ScriptedStation fake(station, payload_,
                       [](int, std::uint64_t offset) { return offset == 2 * kChunk; });
  const FetchResult got = Fetch(station);
  EXPECT_EQ(got.status, FetchStatus::kTransferFailed);
  EXPECT_NE(got.message.find("expected file 0 at offset 8192, got file 0 at offset 12288"),
            std::string::npos)
      << got.message;
  EXPECT_EQ(got.retries, 0);
  EXPECT_EQ(fake.gets(), 1);
  EXPECT_FALSE(std::filesystem::exists(out_dir_ + "/mesh.glb"));
}

}  // namespace
}  // namespace craftscan::client
