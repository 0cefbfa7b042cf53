// placeholder (issue 8)
#include <gtest/gtest.h>
