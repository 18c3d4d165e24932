// End-to-end tests of `zona analytic maxwell|membrane|modulus`: values, --json, errors.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include <nlohmann/json.hpp>

#include "tests/apps/cli_runner.h"

namespace {

using zona::test::CliRun;
using zona::test::run_zona;

namespace fs = std::filesystem;

TEST(CmdAnalytic, MaxwellEq8JsonMatchesTheHandValue) {
  const CliRun r = run_zona("analytic maxwell --deformation 300um --speed 0.1mm/s --time 3s --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  EXPECT_NEAR(j["force_N"].get<double>(), 0.9031057653117864e-3, 1e-12);  // analytic_test.cpp
  EXPECT_NEAR(j["time_s"].get<double>(), 3.0, 1e-12);
}

TEST(CmdAnalytic, MaxwellEq6WithItsOwnSolidAndDefaultTime) {
  // k1 3 N/m, arm 2 (2 N/m, 4 N*s/m); X 2 mm at 1 mm/s: t = X / V = 2 s, 0.006 + 0.004 / e.
  const CliRun r = run_zona(
      "analytic maxwell --deformation 2mm --speed 1mm/s --k1 3N/m --k2 2N/m --c2 4N*s/m --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  EXPECT_NEAR(j["force_N"].get<double>(), 0.00747151776468577, 1e-12);
  EXPECT_NEAR(j["time_s"].get<double>(), 2.0, 1e-12);
}

TEST(CmdAnalytic, MembraneSolvesForTheMissingQuantity) {
  // The seed's chorion is the default geometry (3 um, 400 um, 30 um, nu 0.5).
  CliRun r = run_zona("analytic membrane --young 1.32MPa --deformation 300um --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  nlohmann::json j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["solved"], "force");
  EXPECT_NEAR(j["force_N"].get<double>(), 0.8499939387109278e-3, 1e-12);
  r = run_zona("analytic membrane --force 0.8499939387109278mN --deformation 300um --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["solved"], "young");
  EXPECT_NEAR(j["young_Pa"].get<double>(), 1.32e6, 1.0);
  r = run_zona("analytic membrane --force 0.85mN --young 1.32MPa");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("solved for deformation"), std::string::npos) << r.out;
}

TEST(CmdAnalytic, ModulusPrintsEq9) {
  const CliRun r = run_zona("analytic modulus --speed 0.6mm/s --speed 1mm/s --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  ASSERT_EQ(j["values"].size(), 2u);
  EXPECT_NEAR(j["values"][0]["young_Pa"].get<double>(), 411.1111111111111e6, 1.0);
  EXPECT_NEAR(j["values"][1]["young_Pa"].get<double>(), 500e6, 1.0);
  const CliRun text = run_zona("analytic modulus");
  ASSERT_EQ(text.exit_code, 0) << text.err;
  EXPECT_NE(text.out.find("411.111 MPa"), std::string::npos) << text.out;
}

TEST(CmdAnalytic, BadInputIsOneLineError) {
  CliRun r = run_zona("analytic membrane --force 1mN");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("give two of"), std::string::npos) << r.err;
  r = run_zona("analytic maxwell --deformation 3kPa");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("--deformation"), std::string::npos) << r.err;
  r = run_zona("analytic membrane --load-radius 500um --force 1mN --deformation 100um");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("load_radius"), std::string::npos) << r.err;
}

}  // namespace

TEST(CmdAnalytic, MaxwellTextIsThreeWholeLines) {
  // The default time X / V is said on the deformation line, not as a stray "(null)".
  const CliRun r = run_zona("analytic maxwell");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.out.find("(null)"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("  deformation 300 um, speed 0.1 mm/s, time 3 s (X / V)\n  force "),
            std::string::npos)
      << r.out;
  EXPECT_EQ(std::count(r.out.begin(), r.out.end(), '\n'), 3) << r.out;
  const CliRun given = run_zona("analytic maxwell --time 2s");
  EXPECT_NE(given.out.find("time 2 s\n  force "), std::string::npos) << given.out;
}
