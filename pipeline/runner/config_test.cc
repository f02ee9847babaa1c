// Config loading: errors name the file, line and key, suggest the nearest key, and say the
// expected type; variables expand; holdout selection; --set overrides.
#include "pipeline/runner/config.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>

#include "pipeline/runner/fake_stages_for_test.h"

namespace fs = std::filesystem;

namespace ibmr {
namespace {

class ConfigTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("ibmr_config_test_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
    testing_stages::Register(&registry_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string Write(const std::string& text) {
    const std::string path = (dir_ / "c.yaml").string();
    std::ofstream(path) << text;
    return path;
  }
  // The error message of loading `text`, or "" when it loads.
  std::string ErrorOf(const std::string& text) {
    try {
      LoadConfig(Write(text), registry_);
    } catch (const ConfigError& e) {
      return e.what();
    }
    return "";
  }

  fs::path dir_;
  StageRegistry registry_;
};

TEST_F(ConfigTest, LoadsDefaultsAndResolvesPaths) {
  const Config config = LoadConfig(Write("workspace: ws\nstages:\n  - produce:\n      value: 3\n  - consume\n"), registry_);
  ASSERT_EQ(config.stages.size(), 2u);
  EXPECT_EQ(config.stages[0].params.Int("value"), 3);
  EXPECT_EQ(config.stages[0].params.String("source"), (dir_ / "source.txt").string());
  EXPECT_EQ(config.stages[1].params.String("suffix"), "x");
  EXPECT_EQ(config.workspace, (dir_ / "ws").string());
  EXPECT_EQ(config.stages[0].key_lines.at("value"), 4);
}

TEST_F(ConfigTest, UnknownParameterNamesLineKeyAndSuggestion) {
  const std::string error = ErrorOf("workspace: ws\nstages:\n  - produce:\n      valeu: 3\n");
  EXPECT_NE(error.find("c.yaml:4"), std::string::npos) << error;
  EXPECT_NE(error.find("produce.valeu"), std::string::npos) << error;
  EXPECT_NE(error.find("did you mean 'value'"), std::string::npos) << error;
}

TEST_F(ConfigTest, TypeErrorSaysExpectedType) {
  const std::string error = ErrorOf("workspace: ws\nstages:\n  - produce:\n      value: many\n");
  EXPECT_NE(error.find("c.yaml:4"), std::string::npos) << error;
  EXPECT_NE(error.find("expected integer"), std::string::npos) << error;
  EXPECT_NE(error.find("'many'"), std::string::npos) << error;
}

// "inf" and "nan" read as numbers (std::stod takes them), but no parameter means either: a bound
// of infinity made the plane sweep's planes and depths infinite, not an error.
TEST_F(ConfigTest, NonFiniteNumbersAreTypeErrors) {
  for (const std::string text : {"inf", "-inf", "nan", "NAN"}) {
    const std::string error = ErrorOf("workspace: ws\nstages:\n  - produce:\n      scale: " + text + "\n");
    EXPECT_NE(error.find("c.yaml:4"), std::string::npos) << error;
    EXPECT_NE(error.find("expected a finite number, got '" + text + "'"), std::string::npos) << error;
  }
  EXPECT_EQ(ErrorOf("workspace: ws\nstages:\n  - produce:\n      scale: 2.5e3\n"), "");
}

// Integers beyond 32 bits are type errors: stages keep counts in int, where 4294967297 would wrap
// to 1 after passing a range check on the 64-bit value.
TEST_F(ConfigTest, IntegersBeyond32BitsAreTypeErrors) {
  for (const std::string text : {"4294967297", "-2147483649"}) {
    const std::string error = ErrorOf("workspace: ws\nstages:\n  - produce:\n      value: " + text + "\n");
    EXPECT_NE(error.find("c.yaml:4"), std::string::npos) << error;
    EXPECT_NE(error.find("within 32 bits (no parameter needs more), got '" + text + "'"), std::string::npos) << error;
  }
  EXPECT_EQ(ErrorOf("workspace: ws\nstages:\n  - produce:\n      value: 2147483647\n"), "");
}

TEST_F(ConfigTest, StageCheckErrorNamesTheKeyLine) {
  const std::string error = ErrorOf("workspace: ws\nstages:\n  - produce:\n      threads: 2\n      value: -4\n");
  EXPECT_NE(error.find("c.yaml:5"), std::string::npos) << error;
  EXPECT_NE(error.find("produce.value"), std::string::npos) << error;
  EXPECT_NE(error.find("must be >= 0"), std::string::npos) << error;
}

TEST_F(ConfigTest, UnknownStageAndTopLevelKeys) {
  std::string error = ErrorOf("workspace: ws\nstages:\n  - prodce\n");
  EXPECT_NE(error.find("c.yaml:3"), std::string::npos) << error;
  EXPECT_NE(error.find("did you mean 'produce'"), std::string::npos) << error;
  error = ErrorOf("workspace: ws\nstage:\n  - produce\n");
  EXPECT_NE(error.find("c.yaml:2"), std::string::npos) << error;
  EXPECT_NE(error.find("did you mean 'stages'"), std::string::npos) << error;
  error = ErrorOf("workspace: ws\nholdout:\n  evry: 8\nstages:\n  - produce\n");
  EXPECT_NE(error.find("holdout.evry"), std::string::npos) << error;
  error = ErrorOf("workspace: ws\nstages:\n  - produce:\n    value: [1\n");
  EXPECT_NE(error.find("YAML syntax error"), std::string::npos) << error;
}

TEST_F(ConfigTest, ExpandsVariablesWithDefaults) {
  ::setenv("IBMR_TEST_VALUE", "7", 1);
  ::unsetenv("IBMR_TEST_UNSET");
  EXPECT_EQ(ExpandVariables("a ${IBMR_TEST_VALUE} b ${IBMR_TEST_UNSET:-d/e} c"), "a 7 b d/e c");
  const Config config = LoadConfig(Write("workspace: ${IBMR_TEST_UNSET:-w2}\nstages:\n  - produce: {value: ${IBMR_TEST_VALUE}}\n"),
                                   registry_);
  EXPECT_EQ(config.stages[0].params.Int("value"), 7);
  EXPECT_EQ(config.workspace, (dir_ / "w2").string());
}

TEST_F(ConfigTest, UnsetVariableWithoutDefaultNamesFileLineAndVariable) {
  ::unsetenv("IBMR_TEST_UNSET");
  // Was: expanded to nothing, read as null, and a stage failed late on a path ".../null".
  std::string error = ErrorOf("workspace: ws\n# ${IBMR_TEST_UNSET} in a comment is ignored\ninputs:\n"
                              "  images: ${IBMR_TEST_UNSET}   # required\nstages:\n  - produce\n");
  EXPECT_NE(error.find("c.yaml:4: ${IBMR_TEST_UNSET} is not set"), std::string::npos) << error;
  EXPECT_NE(error.find("IBMR_TEST_UNSET=..."), std::string::npos) << error;
  EXPECT_NE(error.find("${IBMR_TEST_UNSET:-...}"), std::string::npos) << error;
  ::setenv("IBMR_TEST_EMPTY", "", 1);
  error = ErrorOf("workspace: ${IBMR_TEST_EMPTY}\nstages:\n  - produce\n");
  EXPECT_NE(error.find("c.yaml:1: ${IBMR_TEST_EMPTY} is empty"), std::string::npos) << error;
  // An empty default is a default.
  EXPECT_EQ(ErrorOf("workspace: ws${IBMR_TEST_UNSET:-}\nstages:\n  - produce\n"), "");
  EXPECT_THROW(ExpandVariables("a: ${IBMR_TEST_UNSET}\n", "x.yaml"), ConfigError);
}

// Was: ResolvePath kept an empty workspace "", and the runner made records/, images/, ... at the
// filesystem root.
TEST_F(ConfigTest, EmptyOrRootWorkspaceIsAnError) {
  ::unsetenv("IBMR_TEST_UNSET");
  for (const std::string value : {"\"\"", "${IBMR_TEST_UNSET:-}", "''"}) {
    const std::string error = ErrorOf("stages:\n  - produce\nworkspace: " + value + "\n");
    EXPECT_NE(error.find("c.yaml:3: key 'workspace': is empty: give the folder"), std::string::npos) << value << ": " << error;
  }
  std::string up;
  for (int i = 0; i < 40; ++i) up += "../";
  for (const std::string value : {std::string("/"), up, std::string("/tmp/..")}) {
    const std::string error = ErrorOf("workspace: " + value + "\nstages:\n  - produce\n");
    EXPECT_NE(error.find("c.yaml:1: key 'workspace'"), std::string::npos) << value << ": " << error;
    EXPECT_NE(error.find("is the filesystem root /: give a folder of its own"), std::string::npos) << error;
  }
  EXPECT_NE(ErrorOf("workspace:\nstages:\n  - produce\n").find("key 'workspace': missing"), std::string::npos);
  EXPECT_NE(ErrorOf("workspace: [a]\nstages:\n  - produce\n").find("c.yaml:1: key 'workspace': expected a folder, got a list"),
            std::string::npos);
}

// Was: ${VAR} spliced into the YAML text, so a value's " #" started a comment and its ": " made
// a map (a syntax error blamed on the config).
TEST_F(ConfigTest, VariableValuesStayOneValue) {
  ::setenv("IBMR_TEST_IMAGES", "/x/photos #1", 1);
  ::setenv("IBMR_TEST_COLON", "/x/a: b", 1);
  ::setenv("IBMR_TEST_VALUE", "7", 1);
  const Config config = LoadConfig(Write("workspace: ${IBMR_TEST_COLON}\ninputs:\n  images: ${IBMR_TEST_IMAGES}\n"
                                         "  quoted: \"${IBMR_TEST_IMAGES}/sub\"\n"
                                         "stages:\n  - produce: {value: ${IBMR_TEST_VALUE}, source: ${IBMR_TEST_IMAGES}}\n"),
                                   registry_);
  EXPECT_EQ(config.workspace, "/x/a: b");
  EXPECT_EQ(config.inputs.at("images"), "/x/photos #1");
  EXPECT_EQ(config.inputs.at("quoted"), "/x/photos #1/sub");
  EXPECT_EQ(config.stages[0].params.Int("value"), 7);
  EXPECT_EQ(config.stages[0].params.String("source"), "/x/photos #1");
}

// Each of these aborted the program (an uncaught YAML::TypedBadConversion, exit 134), or read a
// null input as a folder named "null".
TEST_F(ConfigTest, MalformedShapesAreConfigErrors) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"workspace: ws\ninputs: {images: [/a, /b]}\nstages:\n  - produce\n",
       "c.yaml:2: key 'inputs.images': expected a path, got a list"},
      {"workspace: ws\ninputs: {images: {a: 1}}\nstages:\n  - produce\n",
       "c.yaml:2: key 'inputs.images': expected a path, got a map"},
      {"workspace: ws\ninputs: {images: }\nstages:\n  - produce\n",
       "c.yaml:2: key 'inputs.images': expected a path, got nothing"},
      {"workspace: ws\ninputs:\n  images: ''\nstages:\n  - produce\n",
       "c.yaml:3: key 'inputs.images': expected a path, got an empty one"},
      {"workspace: ws\n? [a, b]\n: 1\nstages:\n  - produce\n", "c.yaml:2: expected a plain name as key, got a list"},
      {"workspace: ws\nstages:\n  - ? [a, b]\n    : {value: 1}\n", "c.yaml:3: key 'stages': expected a plain name as key"},
      {"workspace: ws\nstages:\n  - produce:\n      ? {a: 1}\n      : 2\n",
       "c.yaml:4: key 'produce': expected a plain name as key, got a map"},
      {"workspace: ws\nholdout:\n  images: [a.png, ~]\nstages:\n  - produce\n",
       "c.yaml:3: key 'holdout.images': expected a list of image names"},
      {"workspace: ws\nsweep:\n  vary: {? [x] : [1]}\nstages:\n  - produce\n", "key 'sweep.vary': expected a plain name"},
      {"workspace: ws\nstages:\n  - consume: {suffix: [a]}\n", "c.yaml:3: key 'consume.suffix': expected string, got a list"},
  };
  for (const auto& [text, expected] : cases) {
    std::string error;
    EXPECT_NO_FATAL_FAILURE(error = ErrorOf(text));
    EXPECT_NE(error.find(expected), std::string::npos) << text << "\n-> " << error;
  }
}

// Was: accepted, the first workspace: winning but the last stage parameter.
TEST_F(ConfigTest, DuplicateKeysAreErrors) {
  std::string error = ErrorOf("workspace: a\nworkspace: b\nstages:\n  - produce\n");
  EXPECT_NE(error.find("c.yaml:2: key 'workspace' appears twice (first on line 1)"), std::string::npos) << error;
  error = ErrorOf("workspace: ws\nstages:\n  - produce:\n      value: 1\n      value: 2\n");
  EXPECT_NE(error.find("c.yaml:5: key 'produce.value' appears twice"), std::string::npos) << error;
  error = ErrorOf("workspace: ws\ninputs: {images: a, images: b}\nstages:\n  - produce\n");
  EXPECT_NE(error.find("c.yaml:2: key 'inputs.images' appears twice"), std::string::npos) << error;
  error = ErrorOf("workspace: ws\nholdout:\n  every: 2\n  every: 3\nstages:\n  - produce\n");
  EXPECT_NE(error.find("c.yaml:4: key 'holdout.every' appears twice"), std::string::npos) << error;
  // The same key in two maps is fine.
  EXPECT_EQ(ErrorOf("workspace: ws\nstages:\n  - produce: {value: 1}\n  - consume: {suffix: y}\n"), "");
}

TEST_F(ConfigTest, HoldoutOffsetErrorNamesItsLine) {
  const std::string error = ErrorOf("workspace: ws\nholdout:\n  every: 4\n  offset: 4\nstages:\n  - produce\n");
  EXPECT_NE(error.find("c.yaml:4: key 'holdout.offset': must be in [0, every) = [0, 4), got 4"), std::string::npos) << error;
}

// A sweep value reaches its variant as text parsed again; one holding " #" was cut short there.
TEST_F(ConfigTest, SweepValuesThatWouldNotReadBackAreErrors) {
  ::setenv("IBMR_TEST_IMAGES", "/x/photos #1", 1);
  const std::string error =
      ErrorOf("workspace: ws\nsweep:\n  vary:\n    consume.suffix: [a, '${IBMR_TEST_IMAGES}']\nstages:\n  - consume\n");
  EXPECT_NE(error.find("c.yaml:4: key 'sweep.vary.consume.suffix': '/x/photos #1' would not read back"),
            std::string::npos) << error;
  EXPECT_EQ(ErrorOf("workspace: ws\nsweep:\n  vary:\n    consume.suffix: [a, b]\nstages:\n  - consume\n"), "");
}

TEST_F(ConfigTest, HoldoutSelectsEveryNthAndNamed) {
  const Config config = LoadConfig(Write("workspace: ws\nholdout:\n  every: 3\n  images: [z.png]\nstages:\n  - produce\n"),
                                   registry_);
  const auto held = config.holdout.Select({"a", "b", "c", "d", "e", "f", "g", "z.png"});
  EXPECT_EQ(held, (std::set<std::string>{"a", "d", "g", "z.png"}));
}

// holdout: {split: test}: every image of the capture's test split is held out; `every`/`offset`
// pick the ones scored within the split, in its sorted order, never training images.
TEST_F(ConfigTest, HoldoutSplitHoldsTheSplitOutAndScoresEveryNthOfIt) {
  const std::map<std::string, std::string> splits = {{"test/r_0.png", "test"}, {"test/r_1.png", "test"},
                                                     {"test/r_2.png", "test"}, {"test/r_3.png", "test"},
                                                     {"test/r_4.png", "test"}, {"train/r_0.png", "train"},
                                                     {"train/r_1.png", "train"}, {"val/r_0.png", "val"}};
  std::vector<std::string> names;
  for (const auto& [name, split] : splits) names.push_back(name);
  const Config all = LoadConfig(Write("workspace: ws\nholdout:\n  split: test\nstages:\n  - produce\n"), registry_);
  const std::set<std::string> tests = {"test/r_0.png", "test/r_1.png", "test/r_2.png", "test/r_3.png", "test/r_4.png"};
  EXPECT_EQ(all.holdout.Select(names, splits), tests);
  EXPECT_TRUE(all.holdout.Scored(names, splits).empty()) << "no every: all held-out views are scored";
  const Config some =
      LoadConfig(Write("workspace: ws\nholdout:\n  split: test\n  every: 2\n  offset: 1\nstages:\n  - produce\n"), registry_);
  EXPECT_EQ(some.holdout.Select(names, splits), tests) << "the unscored test views stay out of training too";
  EXPECT_EQ(some.holdout.Scored(names, splits), (std::set<std::string>{"test/r_1.png", "test/r_3.png"}));
  EXPECT_NE(some.holdout.Describe().find("test split"), std::string::npos) << some.holdout.Describe();
  const std::string error = ErrorOf("workspace: ws\nholdout:\n  split: tset\nstages:\n  - produce\n");
  EXPECT_NE(error.find("c.yaml:3: key 'holdout.split'"), std::string::npos) << error;
}

TEST_F(ConfigTest, SetOverridesAndChecks) {
  Config config = LoadConfig(Write("workspace: ws\nstages:\n  - produce\n"), registry_);
  ApplyOverride("produce.value=12", registry_, &config);
  EXPECT_EQ(config.stages[0].params.Int("value"), 12);
  EXPECT_THROW(ApplyOverride("produce.value=-1", registry_, &config), ConfigError);
  EXPECT_THROW(ApplyOverride("produce.vlue=1", registry_, &config), ConfigError);
  EXPECT_THROW(ApplyOverride("consume.suffix=1", registry_, &config), ConfigError);  // not in this config
  EXPECT_THROW(ApplyOverride("produce.value", registry_, &config), ConfigError);
}

}  // namespace
}  // namespace ibmr
