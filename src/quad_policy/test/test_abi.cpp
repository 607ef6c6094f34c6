// The layout guard of quad_policy/abi.h (a node linked with a library built from other headers).
#include <gtest/gtest.h>

#include "quad_policy/abi.h"

namespace quad_policy {
namespace {

TEST(LayoutGuard, AgreesWithTheLibraryItWasBuiltWith) {
  EXPECT_EQ(LibraryLayoutStamp(), kHeaderLayoutStamp);
  EXPECT_NO_THROW(CheckLibraryLayout());
}

TEST(LayoutGuard, AMismatchNamesBothStampsAndTheFix) {
  EXPECT_EQ(LayoutMismatchMessage(7, 7), "");
  const std::string m = LayoutMismatchMessage(0x1234, 0xabcd);
  EXPECT_NE(m.find("0000000000001234 in the library"), std::string::npos) << m;
  EXPECT_NE(m.find("000000000000abcd here"), std::string::npos) << m;
  EXPECT_NE(m.find("cd build && make"), std::string::npos) << m;
}

TEST(LayoutGuard, TheStampChangesWithASizeOrAnAlignment) {
  struct A {
    double x;
  };
  struct B {
    double x, y;
  };
  struct alignas(16) C {
    double x;
  };
  EXPECT_NE((LayoutStampOf<A>()), (LayoutStampOf<B>()));
  EXPECT_NE((LayoutStampOf<A>()), (LayoutStampOf<C>()));
  EXPECT_NE((LayoutStampOf<A, B>()), (LayoutStampOf<B, A>()));
  EXPECT_EQ((LayoutStampOf<A, B>()), (LayoutStampOf<A, B>()));
}

}  // namespace
}  // namespace quad_policy
