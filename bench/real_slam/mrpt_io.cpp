// Helper for bench/real_slam/make_suite.py: the two places where MRPT's binary formats are
// needed (builds against MRPT 2.5 headers; see make_suite.py for the command line).
//
//   mrpt_io rawlog SCANS.txt OUT.rawlog.gz LX LY LYAW APERTURE MAXRANGE
//       SCANS.txt: one scan per line "stamp odom_x odom_y odom_yaw K r_1 .. r_K" (seconds,
//       metres, radians). Writes an actions/sensory-frames rawlog: per scan one odometry
//       increment (since the previous scan) and one 2D range scan stamped with its own time,
//       which carmen2rawlog in Debian's build does not do (it stamps every observation alike).
//       Readings >= MAXRANGE are no-returns and marked invalid.
//   mrpt_io dump MAP.simplemap
//       One line per keyframe: "stamp mean_x mean_y mean_yaw best_x best_y best_yaw particles",
//       best = the highest-weight particle when the pose is a particle set (RBPF), else the mean.
#include <mrpt/io/CFileGZInputStream.h>
#include <mrpt/io/CFileGZOutputStream.h>
#include <mrpt/maps/CSimpleMap.h>
#include <mrpt/obs/CActionCollection.h>
#include <mrpt/obs/CActionRobotMovement2D.h>
#include <mrpt/obs/CObservation2DRangeScan.h>
#include <mrpt/obs/CSensoryFrame.h>
#include <mrpt/poses/CPose3DPDFParticles.h>
#include <mrpt/serialization/CArchive.h>
#include <mrpt/system/datetime.h>

#include <cstdio>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

using namespace mrpt;

static int write_rawlog(int argc, char** argv)
{
	if (argc != 9)
	{
		std::cerr << "usage: mrpt_io rawlog SCANS.txt OUT.rawlog.gz LX LY LYAW APERTURE MAXRANGE\n";
		return 2;
	}
	std::ifstream in(argv[2]);
	if (!in)
	{
		std::cerr << "cannot open " << argv[2] << "\n";
		return 2;
	}
	const double lx = std::stod(argv[4]), ly = std::stod(argv[5]), lyaw = std::stod(argv[6]);
	const float aperture = std::stof(argv[7]), max_range = std::stof(argv[8]);
	io::CFileGZOutputStream out(argv[3]);
	auto archive = serialization::archiveFrom(out);
	obs::CActionRobotMovement2D::TMotionModelOptions motion;  // MRPT's default Gaussian model
	std::string line;
	poses::CPose2D previous;
	bool first = true;
	size_t count = 0;
	while (std::getline(in, line))
	{
		std::istringstream tokens(line);
		double stamp, ox, oy, oyaw;
		size_t beams;
		if (!(tokens >> stamp >> ox >> oy >> oyaw >> beams)) continue;
		std::vector<float> ranges(beams);
		for (auto& r : ranges) tokens >> r;
		if (!tokens)
		{
			std::cerr << "short scan line " << count + 1 << "\n";
			return 2;
		}
		const auto when = Clock::fromDouble(stamp);
		const poses::CPose2D odometry(ox, oy, oyaw);
		obs::CActionRobotMovement2D movement;
		movement.timestamp = when;
		movement.computeFromOdometry(first ? poses::CPose2D() : odometry - previous, motion);
		movement.rawOdometryIncrementReading = first ? poses::CPose2D() : odometry - previous;
		obs::CActionCollection actions;
		actions.insert(movement);

		auto scan = obs::CObservation2DRangeScan::Create();
		scan->timestamp = when;
		scan->sensorLabel = "LASER";
		scan->aperture = aperture;
		scan->rightToLeft = true;
		scan->maxRange = max_range;
		scan->sensorPose = poses::CPose3D(lx, ly, 0.0, lyaw, 0.0, 0.0);
		scan->resizeScan(beams);
		for (size_t i = 0; i < beams; i++)
		{
			scan->setScanRange(i, ranges[i]);
			scan->setScanRangeValidity(i, ranges[i] > 0.0f && ranges[i] < max_range);
		}
		obs::CSensoryFrame frame;
		frame.insert(scan);
		archive << actions << frame;
		previous = odometry;
		first = false;
		count++;
	}
	std::cerr << "wrote " << count << " scans to " << argv[3] << "\n";
	return count > 0 ? 0 : 2;
}

static int dump_simplemap(int argc, char** argv)
{
	if (argc != 3)
	{
		std::cerr << "usage: mrpt_io dump MAP.simplemap\n";
		return 2;
	}
	maps::CSimpleMap map;
	if (!map.loadFromFile(argv[2]))
	{
		std::cerr << "cannot load " << argv[2] << "\n";
		return 2;
	}
	for (size_t i = 0; i < map.size(); i++)
	{
		const auto [pdf, frame] = map.get(i);
		auto scan = frame->getObservationByClass<obs::CObservation2DRangeScan>();
		if (!scan) continue;
		const poses::CPose3D mean = pdf->getMeanVal();
		poses::CPose3D best = mean;
		size_t particles = 1;
		if (auto set = std::dynamic_pointer_cast<const poses::CPose3DPDFParticles>(pdf))
		{
			particles = set->size();
			best = poses::CPose3D(set->getMostLikelyParticle());
		}
		std::printf(
			"%.6f %.6f %.6f %.9f %.6f %.6f %.9f %zu\n", Clock::toDouble(scan->timestamp),
			mean.x(), mean.y(), mean.yaw(), best.x(), best.y(), best.yaw(), particles);
	}
	return 0;
}

int main(int argc, char** argv)
{
	try
	{
		const std::string mode = argc > 1 ? argv[1] : "";
		if (mode == "rawlog") return write_rawlog(argc, argv);
		if (mode == "dump") return dump_simplemap(argc, argv);
		std::cerr << "usage: mrpt_io rawlog ... | mrpt_io dump ...\n";
		return 2;
	}
	catch (const std::exception& error)
	{
		std::cerr << error.what() << "\n";
		return 1;
	}
}
