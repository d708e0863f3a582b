// SystemdNotifier against a fake service manager socket (path and abstract
// addresses): the datagrams, their order, the sender pid, the watchdog
// interval, and the no-op without NOTIFY_SOCKET.
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <string>

#include "craftscan/daemon/notify.h"
#include "fake_notify_socket.h"

namespace craftscan::daemon {
namespace {

using testing::FakeNotifySocket;
using testing::ScopedEnv;
using namespace std::chrono_literals;

class NotifierSockets : public ::testing::TestWithParam<FakeNotifySocket::Kind> {};

TEST_P(NotifierSockets, SendsTheLifecycleInOrder) {
  FakeNotifySocket manager(GetParam());
  ASSERT_TRUE(manager.ok()) << manager.error();
  ScopedEnv env("NOTIFY_SOCKET", manager.address());
  SystemdNotifier notifier;
  EXPECT_TRUE(notifier.Enabled());

  std::string error;
  ASSERT_TRUE(notifier.Ready("station1: idle", &error)) << error;
  ASSERT_TRUE(notifier.Status("scanning view 2/6", &error)) << error;
  ASSERT_TRUE(notifier.Watchdog(&error)) << error;
  ASSERT_TRUE(notifier.ExtendTimeout(30s, &error)) << error;
  ASSERT_TRUE(notifier.Stopping("checkpointing", &error)) << error;

  auto m = manager.Receive();
  ASSERT_TRUE(m);
  EXPECT_EQ(m->text, "READY=1\nSTATUS=station1: idle");
  EXPECT_EQ(m->pid, ::getpid());  // what NotifyAccess=main checks
  m = manager.Receive();
  ASSERT_TRUE(m);
  EXPECT_EQ(m->text, "STATUS=scanning view 2/6");
  m = manager.Receive();
  ASSERT_TRUE(m);
  EXPECT_TRUE(m->Has("WATCHDOG=1"));
  m = manager.Receive();
  ASSERT_TRUE(m);
  EXPECT_EQ(m->Value("EXTEND_TIMEOUT_USEC"), "30000000");
  m = manager.Receive();
  ASSERT_TRUE(m);
  EXPECT_TRUE(m->Has("STOPPING=1"));
  EXPECT_EQ(m->Value("STATUS"), "checkpointing");
  EXPECT_TRUE(manager.Drain().empty());
}

INSTANTIATE_TEST_SUITE_P(Sockets, NotifierSockets,
                         ::testing::Values(FakeNotifySocket::Kind::kPath,
                                           FakeNotifySocket::Kind::kAbstract),
                         [](const auto& info) {
                           return info.param == FakeNotifySocket::Kind::kPath ? "Path" : "Abstract";
                         });

TEST(Notifier, StatusCannotInjectAssignments) {
  FakeNotifySocket manager;
  ASSERT_TRUE(manager.ok()) << manager.error();
  ScopedEnv env("NOTIFY_SOCKET", manager.address());
  SystemdNotifier notifier;
  ASSERT_TRUE(notifier.Status("object 'egg'\nREADY=1\r\tWATCHDOG=1"));
  ASSERT_TRUE(notifier.Reloading("new config"));
  auto m = manager.Receive();
  ASSERT_TRUE(m);
  EXPECT_EQ(m->Assignments().size(), 1u) << m->text;
  EXPECT_FALSE(m->Has("READY=1"));
  EXPECT_EQ(m->Value("STATUS"), "object 'egg' READY=1  WATCHDOG=1");
  m = manager.Receive();
  ASSERT_TRUE(m);
  EXPECT_TRUE(m->Has("RELOADING=1"));
  EXPECT_EQ(m->Value("STATUS"), "new config");
}

TEST(Notifier, NoSocketIsANoOp) {
  ScopedEnv env("NOTIFY_SOCKET", std::nullopt);
  SystemdNotifier notifier;
  EXPECT_FALSE(notifier.Enabled());
  std::string error;
  EXPECT_TRUE(notifier.Ready("x", &error));
  EXPECT_TRUE(notifier.Watchdog(&error));
  EXPECT_TRUE(notifier.Stopping({}, &error));
  EXPECT_TRUE(error.empty());
}

TEST(Notifier, UnreachableSocketIsAnError) {
  FakeNotifySocket manager;
  ASSERT_TRUE(manager.ok()) << manager.error();
  ScopedEnv env("NOTIFY_SOCKET", manager.address() + ".absent");
  SystemdNotifier notifier;
  std::string error;
  EXPECT_FALSE(notifier.Ready({}, &error));
  EXPECT_NE(error.find("sd_notify: "), std::string::npos) << error;
}

TEST(Notifier, WatchdogIntervalFollowsTheEnvironment) {
  SystemdNotifier notifier;
  {
    ScopedEnv usec("WATCHDOG_USEC", std::nullopt);
    ScopedEnv pid("WATCHDOG_PID", std::nullopt);
    EXPECT_EQ(notifier.WatchdogInterval(), 0us);
    EXPECT_EQ(notifier.WatchdogPingInterval(), 0us);
  }
  {
    ScopedEnv usec("WATCHDOG_USEC", "30000000");
    ScopedEnv pid("WATCHDOG_PID", std::to_string(::getpid()));
    EXPECT_EQ(notifier.WatchdogInterval(), 30s);
    EXPECT_EQ(notifier.WatchdogPingInterval(), 15s);
  }
  {
    ScopedEnv usec("WATCHDOG_USEC", "20000000");
    ScopedEnv pid("WATCHDOG_PID", std::nullopt);  // no pid: meant for us
    EXPECT_EQ(notifier.WatchdogInterval(), 20s);
  }
  {
    ScopedEnv usec("WATCHDOG_USEC", "30000000");
    ScopedEnv pid("WATCHDOG_PID", std::to_string(::getpid() + 1));  // another process's
    EXPECT_EQ(notifier.WatchdogInterval(), 0us);
  }
  {
    ScopedEnv usec("WATCHDOG_USEC", "soon");
    ScopedEnv pid("WATCHDOG_PID", std::nullopt);
    EXPECT_EQ(notifier.WatchdogInterval(), 0us);
  }
}

}  // namespace
}  // namespace craftscan::daemon
