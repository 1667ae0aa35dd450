"""The C++ half of a flight scenario in the ns-3 channel process (``cppdef`` after ``swb``).

Added to the channel ``bench/wifi/channel_cpp.py`` builds, without changing it:

- **mobility**: the scenario's waypoints (``t i x y z`` per line, seconds from the go
  signal, metres) become ``SetPosition`` calls on each node's ``ConstantPositionMobilityModel``
  at go + t, so the YANS channel's log-distance loss, and with it every frame's SNR and
  loss, follows the flight. Waypoints at t <= 0 are applied at once (the formation before
  the start). The go signal is a file the harness creates at the stacks' start release,
  polled every 50 ms of simulation time (Python cannot run inside ``Simulator::Run``).
- **windowed link files**: the channel's own ``link-<i>.json`` averages every neighbour a
  node has *ever* heard, which is right for a static line and wrong in flight (a drone that
  flew away would keep counting). Here, once a second, ``<dir>/link-<i>.json`` is the mean
  signal over the transmitters node i heard in the last ``WINDOW_S`` seconds, or the noise
  floor (SNR 0 dB, ``"origin": "none"``) when it heard nobody: what a real radio's
  station dump shows once its neighbours left. swarmd's ``file`` link source reads these.
- **who heard whom**: ``<dir>/heard.jsonl``, one line a second: seconds since go and, per
  receiver, the transmitters heard in that second with their mean signal (dBm). The
  timeline figure draws the link quality from it.

Everything in the real-time loop is C++ (testbed pitfall 9).
"""

from __future__ import annotations

from typing import Final

WINDOW_S: Final = 2.0

SOURCE: Final = r"""
#include <chrono>
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <unistd.h>
#include <vector>

namespace swbf
{
using namespace ns3;

struct Waypoint { double t; uint32_t i; double x, y, z; };
struct Heard { double last = -1e9; double sumSig = 0; uint32_t cnt = 0; double lastSig = 0; };

static std::vector<Waypoint> g_wps;
static std::vector<std::map<uint32_t, Heard>> g_heard;  // receiver -> transmitter -> heard
static std::map<uint64_t, uint32_t> g_macIdx;
static std::string g_dir, g_goFile;
static double g_goSim = -1.0;
static double g_windowS = 2.0;
static double g_noiseDbm = -94.0;
static std::ofstream g_heardLog;

static uint64_t Key(Mac48Address a)
{
    uint8_t b[6];
    a.CopyTo(b);
    uint64_t k = 0;
    for (int i = 0; i < 6; ++i) k = (k << 8) | b[i];
    return k;
}

static void Sniff(uint32_t i, Ptr<const Packet> p, uint16_t, WifiTxVector, MpduInfo,
                  SignalNoiseDbm sn, uint16_t)
{
    if (p->GetSize() < 10) return;
    WifiMacHeader hdr;
    Ptr<Packet> c = p->Copy();
    c->RemoveHeader(hdr);
    if (hdr.IsCtl() && !hdr.IsRts()) return;  // ACK/CTS carry no transmitter address
    auto it = g_macIdx.find(Key(hdr.GetAddr2()));
    if (it == g_macIdx.end()) return;
    Heard& h = g_heard[i][it->second];
    h.last = Simulator::Now().GetSeconds();
    h.sumSig += sn.signal;
    h.cnt++;
    h.lastSig = sn.signal;
}

static void SetPos(uint32_t i, double x, double y, double z)
{
    NodeList::GetNode(i)->GetObject<MobilityModel>()->SetPosition(Vector(x, y, z));
}

static void WriteAtomic(const std::string& path, const std::string& text)
{
    std::string tmp = path + ".tmp";
    {
        std::ofstream f(tmp, std::ios::trunc);
        f << text;
    }
    std::rename(tmp.c_str(), path.c_str());
}

static void PollGo()
{
    if (access(g_goFile.c_str(), F_OK) == 0) {
        g_goSim = Simulator::Now().GetSeconds();
        for (const Waypoint& w : g_wps) {
            if (w.t > 0) Simulator::Schedule(Seconds(w.t), &SetPos, w.i, w.x, w.y, w.z);
        }
        std::ostringstream o;
        o.precision(17);
        // the wall (under dilation: experiment) clock at go: the stacks' clock. The channel's
        // wall_at_sim0 is read in the first event, after the taps opened, and can be late by
        // seconds; the daemons' records are aligned to this instead
        double wall = std::chrono::duration<double>(
                          std::chrono::system_clock::now().time_since_epoch())
                          .count();
        o << "{\"go_sim_s\": " << g_goSim << ", \"go_wall\": " << wall << "}\n";
        WriteAtomic(g_dir + "/go.json", o.str());
        return;
    }
    Simulator::Schedule(MilliSeconds(50), &PollGo);
}

static void Tick()
{
    double now = Simulator::Now().GetSeconds();
    std::ostringstream line;
    line.precision(6);
    line << "{\"t\": " << (g_goSim < 0 ? -1.0 : now - g_goSim) << ", \"sim_s\": " << now
         << ", \"rx\": [";
    for (size_t i = 0; i < g_heard.size(); ++i) {
        double sig = 0;
        uint32_t n = 0;
        line << (i ? ", " : "") << "{";
        bool first = true;
        for (auto& kv : g_heard[i]) {
            Heard& h = kv.second;
            if (now - h.last <= g_windowS) {
                sig += h.lastSig;
                n++;
            }
            if (h.cnt) {
                line << (first ? "" : ", ") << "\"" << kv.first << "\": " << h.sumSig / h.cnt;
                first = false;
            }
            h.sumSig = 0;
            h.cnt = 0;
        }
        line << "}";
        double s = n ? sig / n : g_noiseDbm;
        std::ostringstream o;
        o.precision(6);
        o << "{\"signal_dbm\": " << s << ", \"noise_dbm\": " << g_noiseDbm
          << ", \"snr_db\": " << (s - g_noiseDbm) << ", \"neighbours\": " << n
          << ", \"origin\": \"" << (n ? "measured" : "none") << "\", \"sim_s\": " << now
          << "}\n";
        WriteAtomic(g_dir + "/link-" + std::to_string(i) + ".json", o.str());
    }
    line << "]}\n";
    g_heardLog << line.str();
    g_heardLog.flush();
    Simulator::Schedule(Seconds(1.0), &Tick);
}

// n nodes (NodeList 0..n-1, as the channel created them); the waypoint file; the output
// directory (link files, heard.jsonl, go.json); the go file the harness creates.
int Install(uint32_t n, const std::string& waypoints, const std::string& dir,
            const std::string& goFile, double windowS, double noiseDbm)
{
    g_dir = dir;
    g_goFile = goFile;
    g_windowS = windowS;
    g_noiseDbm = noiseDbm;
    g_heard.assign(n, {});
    std::ifstream f(waypoints);
    Waypoint w;
    while (f >> w.t >> w.i >> w.x >> w.y >> w.z) {
        if (w.i >= n) return -1;
        g_wps.push_back(w);
        if (w.t <= 0) SetPos(w.i, w.x, w.y, w.z);
    }
    for (uint32_t i = 0; i < n; ++i) {
        Ptr<Node> node = NodeList::GetNode(i);
        for (uint32_t d = 0; d < node->GetNDevices(); ++d) {
            Ptr<WifiNetDevice> dev = DynamicCast<WifiNetDevice>(node->GetDevice(d));
            if (!dev) continue;
            g_macIdx[Key(Mac48Address::ConvertFrom(dev->GetAddress()))] = i;
            dev->GetPhy()->TraceConnectWithoutContext("MonitorSnifferRx",
                                                      MakeBoundCallback(&Sniff, i));
        }
    }
    g_heardLog.open(dir + "/heard.jsonl", std::ios::trunc);
    Simulator::Schedule(Seconds(0.0), &Tick);
    Simulator::Schedule(Seconds(0.0), &PollGo);
    return (int)g_wps.size();
}
}  // namespace swbf
"""
