#include "kscfg/session/ads_access.hpp"

#include "kscfg/link/ams.hpp"

namespace kscfg {

AdsRequests::AdsRequests(AdsClient& client, std::chrono::milliseconds timeout)
    : client_(client), regs_(client, static_cast<unsigned>(timeout.count())) {}

std::vector<DirectAnswer> AdsRequests::run(std::span<const DirectRequest> requests) {
  std::vector<AdsClient::Call> calls;
  for (const auto& r : requests) {
    adsreg::RegisterAccess::Address a;
    a.terminal = r.terminal;
    a.channel = r.key.channel;
    a.reg = r.op.reg;
    calls.push_back(r.op.write ? regs_.write_call(a, r.op.value) : regs_.read_call(a));
  }
  std::vector<AdsClient::Reply> replies = client_.transact(calls);
  std::vector<DirectAnswer> answers(requests.size());
  for (std::size_t i = 0; i < requests.size(); ++i) {
    const bool read = !requests[i].op.write;
    answers[i].error = regs_.reply_error(replies[i], calls[i], read);
    if (read && !answers[i].error) answers[i].value = ams::get16(replies[i].data.data());
  }
  return answers;
}

}  // namespace kscfg
