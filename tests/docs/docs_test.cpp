// Tests of the documentation against the project: every file a page names exists, every
// reference anchor a page links to is defined, and docs/scenes.md quotes the shipped scenes'
// own values (E, diameter, needle speed), so that a newcomer meets no contradiction.
#include <gtest/gtest.h>

#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <regex>
#include <set>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace {

namespace fs = std::filesystem;
const fs::path kRoot = ZONA_SOURCE_DIR;

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

// The pages a user reads: README, docs/, and the READMEs of bench, fuzz and the test data.
std::vector<fs::path> pages() {
  std::vector<fs::path> out = {kRoot / "README.md", kRoot / "bench/README.md",
                               kRoot / "fuzz/README.md", kRoot / "tests/data/README.md"};
  for (const fs::directory_entry& e : fs::directory_iterator(kRoot / "docs"))
    if (e.path().extension() == ".md") out.push_back(e.path());
  return out;
}

// 1-based line of a character offset, for messages.
int line_of(const std::string& text, size_t offset) {
  return 1 + static_cast<int>(std::count(text.begin(), text.begin() + static_cast<long>(offset), '\n'));
}

TEST(Docs, NoPageNamesAFileThatIsNotThere) {
  // Markdown links (relative to the page) and project paths in the text (relative to the root).
  const std::regex link(R"(\]\(([^)#\s]+)(#[^)\s]*)?\))");
  const std::regex path(
      R"(\b((?:docs|engine|apps|kernels|render|shaders|scenes|bench|tests|scripts|fuzz|cmake)/[A-Za-z0-9_./-]*[A-Za-z0-9_-]\.(?:md|cpp|h|cu|cuh|json|csv|sh|py|png|svg|txt|glsl|comp|vert|frag|geo|msh|poly|node|ele))\b)");
  int checked = 0;
  for (const fs::path& page : pages()) {
    const std::string text = slurp(page);
    ASSERT_FALSE(text.empty()) << page;
    EXPECT_EQ(text.find("DESIGN.md"), std::string::npos) << page << ": cites DESIGN.md";
    for (std::sregex_iterator it(text.begin(), text.end(), link), end; it != end; ++it) {
      const std::string target = (*it)[1];
      if (target.find("://") != std::string::npos || target.rfind("mailto:", 0) == 0) continue;
      ++checked;
      EXPECT_TRUE(fs::exists(page.parent_path() / target))
          << page.lexically_relative(kRoot).string() << ":" << line_of(text, it->position())
          << ": link to " << target << ", which does not exist";
    }
    for (std::sregex_iterator it(text.begin(), text.end(), path), end; it != end; ++it) {
      const std::string target = (*it)[1];
      ++checked;
      EXPECT_TRUE(fs::exists(kRoot / target))
          << page.lexically_relative(kRoot).string() << ":" << line_of(text, it->position())
          << ": names " << target << ", which does not exist";
    }
  }
  EXPECT_GT(checked, 100);  // the patterns do find the pages' references
}

TEST(Docs, ReferenceAnchorsAreDefined) {
  const std::string refs = slurp(kRoot / "docs/references.md");
  std::set<std::string> anchors;
  const std::regex anchor(R"re(<a id="([a-z0-9_-]+)"></a>)re");
  for (std::sregex_iterator it(refs.begin(), refs.end(), anchor), end; it != end; ++it)
    anchors.insert((*it)[1]);
  for (const char* id : {"ladjal", "asgari", "hajiyavand", "smith2018", "labelle2007"})
    EXPECT_TRUE(anchors.count(id)) << id;
  const std::regex use(R"(references\.md#([a-z0-9_-]+))");
  for (const fs::path& page : pages()) {
    const std::string text = slurp(page);
    for (std::sregex_iterator it(text.begin(), text.end(), use), end; it != end; ++it)
      EXPECT_TRUE(anchors.count((*it)[1])) << page << ": #" << (*it)[1] << " is not in references.md";
    // The papers go by their authors, not by the project's internal file numbers.
    EXPECT_FALSE(std::regex_search(text, std::regex(R"(\b[Ss]eeds? ?00[0-2]\b)"))) << page;
  }
}

TEST(Docs, SourcesCiteThePapersByAuthor) {
  // Code comments, help texts and scene notes name the papers as the pages do (docs/references.md)
  // and cite no DESIGN.md, which is not in the project. bench/results holds measured files,
  // whose header lines are rewritten when a benchmark is run again.
  const std::regex seed(R"(\b[Ss]eeds? ?00[0-2]\b)");
  int files = 0;
  for (const char* folder : {"engine", "kernels", "apps", "render", "shaders", "bench", "tests",
                             "scenes", "python", "scripts"}) {
    if (!fs::exists(kRoot / folder)) continue;
    for (const fs::directory_entry& e : fs::recursive_directory_iterator(kRoot / folder)) {
      const std::string ext = e.path().extension().string();
      if (!e.is_regular_file() || e.path().string().find("/bench/results/") != std::string::npos ||
          e.path().filename() == "docs_test.cpp")
        continue;
      if (ext != ".h" && ext != ".cpp" && ext != ".cu" && ext != ".cuh" && ext != ".json" &&
          ext != ".py" && ext != ".sh" && ext != ".comp" && ext != ".vert" && ext != ".frag")
        continue;
      ++files;
      const std::string text = slurp(e.path());
      const std::string name = e.path().lexically_relative(kRoot).string();
      EXPECT_EQ(text.find("DESIGN.md"), std::string::npos) << name << ": cites DESIGN.md";
      std::smatch m;
      if (std::regex_search(text, m, seed))
        ADD_FAILURE() << name << ":" << line_of(text, static_cast<size_t>(m.position(0)))
                      << ": names a paper '" << m.str(0) << "' (docs/references.md has its authors)";
    }
  }
  EXPECT_GT(files, 100);
}

TEST(Docs, ReadmeHasARowForEveryCommand) {
  // The subcommands `zona --help` lists; each has a row in README's command table.
  const std::string out = (fs::temp_directory_path() / ("zona_docs_help_" + std::to_string(::getpid()))).string();
  ASSERT_EQ(std::system((std::string(ZONA_CLI_PATH) + " --help >" + out).c_str()), 0);
  const std::string help = slurp(out);
  fs::remove(out);
  const size_t list = help.find("Subcommands:");
  ASSERT_NE(list, std::string::npos) << help;
  const std::string readme = slurp(kRoot / "README.md");
  const std::regex name(R"(\n  ([a-z]+) )");
  int commands = 0;
  const std::string tail = help.substr(list);
  for (std::sregex_iterator it(tail.begin(), tail.end(), name), end; it != end; ++it) {
    ++commands;
    EXPECT_NE(readme.find("| `zona " + (*it)[1].str()), std::string::npos)
        << "README.md's command table has no row for zona " << (*it)[1];
  }
  EXPECT_GE(commands, 12);
}

TEST(Docs, ScenesPageQuotesEveryShippedScenesOwnValues) {
  // Each shipped scene has a row in docs/scenes.md's table, and the row's E, diameter and
  // needle speed are the scene file's (a calibrated E changed in the scene shows up here).
  const std::string page = slurp(kRoot / "docs/scenes.md");
  int scenes = 0;
  for (const fs::directory_entry& e : fs::directory_iterator(kRoot / "scenes")) {
    if (e.path().extension() != ".json") continue;
    ++scenes;
    const std::string name = e.path().filename().string();
    const size_t at = page.find("| `scenes/" + name + "` |");
    ASSERT_NE(at, std::string::npos) << "docs/scenes.md has no row for scenes/" << name;
    const std::string row = page.substr(at, page.find('\n', at) - at);
    std::ifstream in(e.path());
    nlohmann::json scene = nlohmann::json::parse(in);  // operator[] on missing keys gives null
    const nlohmann::json young = scene["materials"]["default"]["young"];
    if (young.is_string()) {
      EXPECT_NE(row.find("E " + young.get<std::string>()), std::string::npos)
          << name << ": row should say E " << young.get<std::string>() << "\n" << row;
    }
    const nlohmann::json diameter = scene["mesh"]["generate"]["diameter"];
    if (diameter.is_string()) {
      EXPECT_NE(row.find(diameter.get<std::string>()), std::string::npos)
          << name << ": row should say " << diameter.get<std::string>() << "\n" << row;
    }
    const nlohmann::json speed = scene["needle"]["speed"];
    if (speed.is_string()) {
      EXPECT_NE(row.find(speed.get<std::string>()), std::string::npos)
          << name << ": row should say " << speed.get<std::string>() << "\n" << row;
    }
  }
  EXPECT_GE(scenes, 6);
}

}  // namespace
