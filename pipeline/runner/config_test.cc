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

TEST_F(ConfigTest, HoldoutSelectsEveryNthAndNamed) {
  const Config config = LoadConfig(Write("workspace: ws\nholdout:\n  every: 3\n  images: [z.png]\nstages:\n  - produce\n"),
                                   registry_);
  const auto held = config.holdout.Select({"a", "b", "c", "d", "e", "f", "g", "z.png"});
  EXPECT_EQ(held, (std::set<std::string>{"a", "d", "g", "z.png"}));
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
