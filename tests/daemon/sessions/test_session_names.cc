// Session naming rules, state names and transitions, and the manifest's JSON
// form (round trip, validation of corrupt manifests).
#include <gtest/gtest.h>

#include <string>
#include <utility>

#include "craftscan/daemon/session_manifest.h"

namespace craftscan::daemon {
namespace {

TEST(SanitizeObjectName, KeepsSafeNamesAndNeutralisesTraversal) {
  const std::pair<std::string, std::string> cases[] = {
      {"carved-egg_01.v2", "carved-egg_01.v2"},
      {"carved egg", "carved_egg"},
      {"../../etc", "etc"},
      {"../../etc/passwd", "etc_passwd"},
      {"a/b", "a_b"},
      {"a\\b", "a_b"},
      {".hidden", "hidden"},
      {"-rf", "rf"},
      {"--help", "help"},
      {"a..b", "a.b"},
      {"tab\there\nnewline\x7f", "tab_here_newline"},
      {std::string("nul\0byte", 8), "nul_byte"},
      // "Ägg-Ω" in UTF-8: each non-ASCII byte becomes '_', runs collapse.
      {"\xc3\x84gg-\xce\xa9", "gg-"},
      {"\xe5\xb5\x8c\xe7\xb9\xa1 sampler", "sampler"},
      {"", "object"},
      {"...", "object"},
      {"/", "object"},
      {"\xff\xfe", "object"},
      {std::string(300, 'x'), std::string(64, 'x')},
      // Truncation never leaves a trailing '_'.
      {std::string(63, 'y') + "  z", std::string(63, 'y')},
  };
  for (const auto& [input, expected] : cases) {
    EXPECT_EQ(SanitizeObjectName(input), expected) << "input '" << input << "'";
  }
}

TEST(SanitizeObjectName, EveryResultMakesAValidIdThatIsOneFolderComponent) {
  const std::string inputs[] = {"../../etc",
                                "a/b",
                                ".hidden",
                                "-rf",
                                "..",
                                ".",
                                "",
                                std::string(300, '/'),
                                "\xc3\x84\xc3\x84",
                                "x/../../y",
                                " -.- ",
                                "~root",
                                "$(rm -rf /)",
                                "C:\\Windows"};
  for (const auto& input : inputs) {
    const std::string name = SanitizeObjectName(input);
    SCOPED_TRACE("input '" + input + "' -> '" + name + "'");
    EXPECT_FALSE(name.empty());
    EXPECT_LE(name.size(), 64u);
    EXPECT_EQ(name.find('/'), std::string::npos);
    EXPECT_EQ(name.find(".."), std::string::npos);
    EXPECT_NE(name.front(), '.');
    EXPECT_NE(name.front(), '-');
    EXPECT_TRUE(IsValidSessionId("20240501-093000-" + name));
    EXPECT_TRUE(IsValidSessionId("20240501-093000-" + name + "-999"));
  }
}

TEST(SessionId, AcceptsOnlyTheExactShape) {
  EXPECT_TRUE(IsValidSessionId("20240501-093000-egg"));
  EXPECT_TRUE(IsValidSessionId("20240501-093000-egg-2"));
  EXPECT_TRUE(IsValidSessionId("20240501-093000-" + std::string(64, 'a') + "-999"));
  EXPECT_FALSE(IsValidSessionId("20240501-093000-" + std::string(64, 'a') + "-1000"));
  EXPECT_FALSE(IsValidSessionId(""));
  EXPECT_FALSE(IsValidSessionId("../x"));
  EXPECT_FALSE(IsValidSessionId("a/b"));
  EXPECT_FALSE(IsValidSessionId(".."));
  EXPECT_FALSE(IsValidSessionId("20240501-093000-"));
  EXPECT_FALSE(IsValidSessionId("20240501-093000-../etc"));
  EXPECT_FALSE(IsValidSessionId("20240501-093000-egg/../../x"));
  EXPECT_FALSE(IsValidSessionId("20240501-093000-.hidden"));
  EXPECT_FALSE(IsValidSessionId("20240501-093000--rf"));
  EXPECT_FALSE(IsValidSessionId("20240501-093000-a..b"));
  EXPECT_FALSE(IsValidSessionId("2024050-1093000-egg"));
  EXPECT_FALSE(IsValidSessionId("2024O501-093000-egg"));
  EXPECT_FALSE(IsValidSessionId("20240501_093000-egg"));
  EXPECT_FALSE(IsValidSessionId("20240501-093000-egg "));
  EXPECT_FALSE(IsValidSessionId(std::string("20240501-093000-egg\0x", 21)));
}

TEST(OutputName, AcceptsOutputsAndRefusesEscapesAndReservedNames) {
  for (const char* ok : {"fused.ply", "mesh.ply", "report.json", "report.html",
                         "previews/view003.png", "a/b/c/d.txt"}) {
    std::string why;
    EXPECT_TRUE(IsValidOutputName(ok, &why)) << ok << ": " << why;
  }
  const std::pair<const char*, const char*> bad[] = {
      {"", "empty"},
      {"/etc/passwd", "absolute"},
      {"../x", "'..'"},
      {"previews/../../x", "'..'"},
      {"a//b", "empty component"},
      {"previews/", "empty component"},
      {".hidden", "starting with '.'"},
      {"previews/.x.png", "starting with '.'"},
      {"-rf", "starting with '.' or '-'"},
      {"a b", "character"},
      {"a\\b", "character"},
      {"a/b/c/d/e", "more than 4"},
      {"manifest.json", "reserved"},
      {"calibration.yaml", "reserved"},
      {"views/000/left.png", "reserved views/"},
      {"views", "reserved views/"},
  };
  for (const auto& [name, reason] : bad) {
    std::string why;
    EXPECT_FALSE(IsValidOutputName(name, &why)) << name;
    EXPECT_NE(why.find(reason), std::string::npos) << name << ": " << why;
  }
  std::string why;
  EXPECT_FALSE(IsValidOutputName(std::string(201, 'a'), &why));
}

TEST(SessionStateNames, NamesRoundTripAndTransitionsFollowTheMachine) {
  using S = SessionState;
  for (S s :
       {S::kCreated, S::kCapturing, S::kReconstructing, S::kDone, S::kInterrupted, S::kFailed}) {
    S back = S::kDone;
    ASSERT_TRUE(SessionStateFromString(ToString(s), &back)) << ToString(s);
    EXPECT_EQ(back, s);
    EXPECT_FALSE(IsAllowedTransition(S::kDone, s));  // done is final
    EXPECT_FALSE(IsAllowedTransition(s, s));
  }
  S out = S::kDone;
  EXPECT_FALSE(SessionStateFromString("Capturing", &out));
  EXPECT_FALSE(SessionStateFromString("corrupt", &out));
  EXPECT_TRUE(IsAllowedTransition(S::kCreated, S::kCapturing));
  EXPECT_TRUE(IsAllowedTransition(S::kCapturing, S::kReconstructing));
  EXPECT_TRUE(IsAllowedTransition(S::kCapturing, S::kDone));
  EXPECT_TRUE(IsAllowedTransition(S::kReconstructing, S::kDone));
  EXPECT_TRUE(IsAllowedTransition(S::kInterrupted, S::kCapturing));
  EXPECT_TRUE(IsAllowedTransition(S::kFailed, S::kReconstructing));
  EXPECT_FALSE(IsAllowedTransition(S::kCreated, S::kDone));
  EXPECT_FALSE(IsAllowedTransition(S::kReconstructing, S::kCapturing));
  EXPECT_FALSE(IsAllowedTransition(S::kFailed, S::kInterrupted));
  EXPECT_TRUE(IsActive(S::kCreated) && IsActive(S::kCapturing) && IsActive(S::kReconstructing));
  EXPECT_FALSE(IsActive(S::kDone) || IsActive(S::kInterrupted) || IsActive(S::kFailed));
}

TEST(Fnv1a64, MatchesPublishedValues) {
  // Reference values of the FNV-1a 64-bit hash (offset basis for "").
  EXPECT_EQ(Fnv1a64(""), 0xcbf29ce484222325ULL);
  EXPECT_EQ(Fnv1a64("a"), 0xaf63dc4c8601ec8cULL);
  EXPECT_EQ(Fnv1a64("foobar"), 0x85944171f73967e8ULL);
}

Manifest SampleManifest() {
  Manifest m;
  m.id = "20240501-093000-egg-2";
  m.object_name = "Ägg \"carved\"";
  m.object = "gg_carved";
  m.job = "scan";
  m.params = {{"views", 24}, {"step_deg", 15.0}, {"exposure_us", 8000}};
  m.state = SessionState::kCapturing;
  m.created_utc = "2024-05-01T09:30:00.000Z";
  m.updated_utc = "2024-05-01T09:30:07.412Z";
  m.calibration_id = "rig-a 2024-04-30";
  m.calibration = FileRecord{2210, 0x9ae16a3b2f90404fULL};
  ViewRecord v;
  v.index = 7;
  v.angle_deg = 105.0;
  v.captured_utc = "2024-05-01T09:30:03.101Z";
  v.files[kLeftPng] = {812345, 0xffffffffffffffffULL};
  v.files[kRightPng] = {812001, 1};
  v.files[kMetaJson] = {120, 0x0123456789abcdefULL};
  v.files[kDisparityPfm] = {4000000, 42};
  m.views[7] = v;
  m.outputs["fused.ply"] = {123456789012ULL, 7, std::string(64, 'a')};
  m.outputs["previews/view007.png"] = {1000, 8};
  m.journal = {{"2024-05-01T09:30:00.000Z", "created", "scan of 'egg'"},
               {"2024-05-01T09:30:01.000Z", "capturing", ""}};
  return m;
}

TEST(ManifestJson, RoundTripsEveryField) {
  const Manifest m = SampleManifest();
  const std::string text = ManifestToJson(m);
  Manifest back;
  std::string error;
  ASSERT_TRUE(ManifestFromJson(text, &back, &error)) << error << "\n" << text;
  EXPECT_EQ(back.id, m.id);
  EXPECT_EQ(back.object_name, m.object_name);
  EXPECT_EQ(back.object, m.object);
  EXPECT_EQ(back.job, m.job);
  EXPECT_EQ(back.params, m.params);
  EXPECT_EQ(back.state, m.state);
  EXPECT_EQ(back.created_utc, m.created_utc);
  EXPECT_EQ(back.updated_utc, m.updated_utc);
  EXPECT_EQ(back.calibration_id, m.calibration_id);
  ASSERT_TRUE(back.calibration.has_value());
  EXPECT_EQ(*back.calibration, *m.calibration);
  ASSERT_EQ(back.views.size(), 1u);
  EXPECT_EQ(back.views.at(7).angle_deg, 105.0);
  EXPECT_EQ(back.views.at(7).captured_utc, m.views.at(7).captured_utc);
  EXPECT_EQ(back.views.at(7).files, m.views.at(7).files);
  EXPECT_TRUE(back.views.at(7).HasCapture() && back.views.at(7).HasDisparity());
  EXPECT_FALSE(back.views.at(7).HasCloud());
  EXPECT_EQ(back.outputs, m.outputs);
  ASSERT_EQ(back.journal.size(), 2u);
  EXPECT_EQ(back.journal[1].event, "capturing");
  EXPECT_EQ(ManifestToJson(back), text);  // stable text
  EXPECT_NE(text.find("\"fnv1a64\": \"ffffffffffffffff\""), std::string::npos) << text;
  EXPECT_EQ(back.outputs.at("fused.ply").sha256, std::string(64, 'a'));
  // A record without SHA-256 (from an old manifest) is written without the key.
  EXPECT_EQ(text.find("\"sha256\""), text.rfind("\"sha256\"")) << text;
}

TEST(ManifestJson, RefusesCorruptManifestsNamingTheField) {
  const std::string good = ManifestToJson(SampleManifest());
  const auto broken = [&](const std::string& from, const std::string& to) {
    std::string text = good;
    const auto at = text.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    return at == std::string::npos ? text : text.replace(at, from.size(), to);
  };
  const std::pair<std::string, std::string> cases[] = {
      {good.substr(0, good.size() / 2), "not valid JSON"},
      {"[]", "not a JSON object"},
      {broken("\"format_version\": 1", "\"format_version\": 2"), "format_version 2"},
      {broken("\"state\": \"capturing\"", "\"state\": \"running\""), "manifest.state 'running'"},
      {broken("\"id\": \"20240501-093000-egg-2\"", "\"id\": \"../x\""), "manifest.id"},
      {broken("\"index\": 7", "\"index\": 1000"), "manifest.views[0].index"},
      {broken("\"size\": 812345", "\"size\": -1"), "views[0].files.left.png.size"},
      {broken("\"ffffffffffffffff\"", "\"FFFF\""), "left.png.fnv1a64"},
      {broken(std::string(64, 'a'), std::string(64, 'A')), "outputs.fused.ply.sha256"},
      {broken("\"" + std::string(64, 'a') + "\"", "7"), "outputs.fused.ply.sha256 is not a string"},
      {broken("\"disparity.pfm\"", "\"evil.sh\""), "unknown file 'evil.sh'"},
      {broken("\"previews/view007.png\"", "\"../../x\""), "manifest.outputs"},
      {broken("\"job\": \"scan\"", "\"job\": 3"), "manifest.job is not a string"},
      {broken("\"journal\": [", "\"journal\": [3, "), "manifest.journal[0] is not an object"},
  };
  for (const auto& [text, reason] : cases) {
    Manifest m;
    std::string error;
    EXPECT_FALSE(ManifestFromJson(text, &m, &error)) << reason;
    EXPECT_NE(error.find(reason), std::string::npos) << "expected '" << reason << "' in: " << error;
  }
}

}  // namespace
}  // namespace craftscan::daemon
