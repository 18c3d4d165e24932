// Sweeps: points from --set lists and manifests, markers, the table and the SLURM script.
#include "engine/analysis/sweep.h"

#include <gtest/gtest.h>
#include <signal.h>

#include <filesystem>
#include <fstream>

namespace zona {
namespace {

namespace fs = std::filesystem;

fs::path temp_file(const std::string& name, const std::string& text) {
  const fs::path p = fs::temp_directory_path() / ("zona_sweep_" + std::to_string(::getpid()) + "_" + name);
  std::ofstream(p) << text;
  return p;
}

TEST(Sweep, ProductOfSetListsAndFixedOverrides) {
  std::vector<std::string> fixed;
  const std::vector<std::string> sets = {"a=1,2", "b=x", "c=p, q ,r"};
  Result<SweepPoints> p = sweep_points_from_sets(sets, &fixed);
  ASSERT_TRUE(p.ok()) << p.error().message;
  EXPECT_EQ(fixed, std::vector<std::string>{"b=x"});
  EXPECT_EQ(p->keys, (std::vector<std::string>{"a", "c"}));
  ASSERT_EQ(p->values.size(), 6u);
  EXPECT_EQ(p->values[0], (std::vector<std::string>{"1", "p"}));
  EXPECT_EQ(p->values[1], (std::vector<std::string>{"1", "q"}));  // the last key fastest
  EXPECT_EQ(p->values[5], (std::vector<std::string>{"2", "r"}));
  fixed.clear();
  const std::vector<std::string> empty_value = {"a=1,,2"};
  Result<SweepPoints> bad = sweep_points_from_sets(empty_value, &fixed);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("--set a: empty value"), std::string::npos) << bad.error().message;
  const std::vector<std::string> no_key = {"=1,2"};
  EXPECT_FALSE(sweep_points_from_sets(no_key, &fixed).ok());
}

TEST(Sweep, ManifestWithQuotesCommentsAndErrors) {
  const fs::path good = temp_file("good.csv",
                                  "# speeds and a direction\npoint,needle.speed,needle.direction\n"
                                  "0,0.1mm/s,\"[0, 0, 1]\"\n1,0.2mm/s,\"[0, 1, 0]\"\n");
  Result<SweepPoints> m = read_sweep_manifest(good.string());
  ASSERT_TRUE(m.ok()) << m.error().message;
  EXPECT_EQ(m->keys, (std::vector<std::string>{"needle.speed", "needle.direction"}));
  EXPECT_EQ(m->values[1][1], "[0, 1, 0]");
  // Written back and read again: the same points.
  const fs::path again = temp_file("again.csv", sweep_manifest_csv(*m));
  Result<SweepPoints> m2 = read_sweep_manifest(again.string());
  ASSERT_TRUE(m2.ok()) << m2.error().message;
  EXPECT_EQ(m2->values, m->values);
  const fs::path short_row = temp_file("short.csv", "a,b\n1,2\n3\n");
  Result<SweepPoints> bad = read_sweep_manifest(short_row.string());
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("short.csv:3: 1 fields, the header has 2"), std::string::npos)
      << bad.error().message;
  const fs::path empty = temp_file("empty.csv", "a,b\n1,\n");
  bad = read_sweep_manifest(empty.string());
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("empty.csv:2: empty value of b"), std::string::npos) << bad.error().message;
  // A manifest with a --set list: every row with every value.
  std::vector<std::string> fixed;
  const std::vector<std::string> sets = {"x=1,2,3"};
  Result<SweepPoints> both = combine_sweep_points(*m, *sweep_points_from_sets(sets, &fixed));
  ASSERT_TRUE(both.ok());
  EXPECT_EQ(both->values.size(), 6u);
  EXPECT_FALSE(combine_sweep_points(*m, *m).ok());  // a key in both
  for (const fs::path& p : {good, again, short_row, empty}) fs::remove(p);
}

TEST(Sweep, OnlyFinalOutcomesMarkAPointDone) {
  WorkerOutcome o;
  o.started = true;
  o.exit_code = 0;
  EXPECT_TRUE(sweep_outcome_is_final(o));
  o.exit_code = 1;
  EXPECT_TRUE(sweep_outcome_is_final(o));  // an error is a result
  const PointRecord failed = sweep_point_record(3, o, "zona run: ...\nzona: error: the run was not quasi-static\n");
  EXPECT_EQ(failed.status, "failed");
  EXPECT_EQ(failed.message, "the run was not quasi-static");
  o.exit_code = 143;  // zona run after SIGTERM: killed from outside, runs again
  EXPECT_FALSE(sweep_outcome_is_final(o));
  o.exit_code = -1;
  o.signal = SIGKILL;
  EXPECT_FALSE(sweep_outcome_is_final(o));
  o.signal = SIGSEGV;
  EXPECT_TRUE(sweep_outcome_is_final(o));
  EXPECT_EQ(sweep_point_record(4, o, "").status, "crashed");
}

TEST(Sweep, MarkerRoundTripAndPendingRows) {
  const fs::path dir = fs::temp_directory_path() / ("zona_sweep_dir_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir / sweep_point_folder(1));
  Result<std::optional<PointRecord>> none = read_point_record(dir.string(), 1);
  ASSERT_TRUE(none.ok());
  EXPECT_FALSE(none->has_value());
  PointRecord r;
  r.index = 1;
  r.status = "failed";
  r.exit_code = 1;
  r.wall_seconds = 0.5;
  r.message = "bad, really";
  ASSERT_TRUE(write_point_record(dir.string(), r).ok());
  Result<std::optional<PointRecord>> back = read_point_record(dir.string(), 1);
  ASSERT_TRUE(back.ok() && back->has_value());
  EXPECT_EQ((*back)->message, "bad, really");
  SweepConfig config;
  config.deformations = {10e-6};
  SweepPoints points{{"k"}, {{"a"}, {"b"}}};
  std::vector<SweepRow> rows = {read_sweep_row(dir.string(), config, 0), read_sweep_row(dir.string(), config, 1)};
  EXPECT_EQ(rows[0].status, "pending");
  EXPECT_EQ(rows[1].status, "failed");
  const std::string table = sweep_table_csv(config, points, rows);
  EXPECT_NE(table.find("point,k,status,exit_code,punctured,puncture_deformation_m,puncture_force_N,"
                       "peak_force_N,force_at_10um_N,quasi_static,wall_s,folder,message\n"),
            std::string::npos)
      << table;
  EXPECT_NE(table.find("0,a,pending,,,,,,,,,points/00000,\n"), std::string::npos) << table;
  EXPECT_NE(table.find("bad; really"), std::string::npos) << table;  // no comma in a field
  fs::remove_all(dir);
}

TEST(Sweep, SlurmScriptRunsOneTaskPerPoint) {
  SlurmOptions o;
  o.gpus_per_task = 1;
  o.max_parallel = 8;
  o.extra = {"--partition=gpu"};
  const std::string s = slurm_script("/opt/zona/bin/zona", "/scratch/sw", 100, o);
  EXPECT_EQ(s.rfind("#!/bin/bash\n", 0), 0u);
  EXPECT_NE(s.find("#SBATCH --array=0-99%8\n"), std::string::npos) << s;
  EXPECT_NE(s.find("#SBATCH --gres=gpu:1\n"), std::string::npos) << s;
  EXPECT_NE(s.find("#SBATCH --partition=gpu\n"), std::string::npos) << s;
  EXPECT_NE(s.find("exec '/opt/zona/bin/zona' sweep --task \"$SLURM_ARRAY_TASK_ID\" --out '/scratch/sw'\n"),
            std::string::npos)
      << s;
}

}  // namespace
}  // namespace zona
