// "Did you mean" for terminal types: neighbours by order number before near spellings.
#pragma once
#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

namespace kscfg {

// Terminal types near a type name by its order number: for "KL6012" the types of the same letters
// and hundred (KL60xx) closest in number, at most `n`, in the order of their numbers (KL6001,
// KL6011, KL6021): a typo in an order number means a neighbour of the same family, rarely the same
// last digits in another (KL1012, KL2012). Empty when `name` is not letters and four digits or
// no candidate shares its hundred.
std::vector<std::string> closest_order_numbers(std::string_view name, const std::vector<std::string>& candidates,
                                               std::size_t n = 3);

// "did you mean KL6001, KL6011 or KL6021?" for a type name: closest_order_numbers, else the
// closest spellings (did_you_mean, base/parse.hpp); "" when there is none.
std::string did_you_mean_type(std::string_view name, const std::vector<std::string>& candidates);

}  // namespace kscfg
