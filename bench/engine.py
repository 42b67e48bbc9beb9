"""Engine throughput benchmark (prints JSON). 

    python bench/engine.py                      # 5v5 and 30v30, batch 1/64/1024/4096
    python bench/engine.py --batch-sizes 1024 --repeats 3

Both CPU cores are exposed to XLA as two host devices (unless XLA_FLAGS already says otherwise);
set XLA_FLAGS=--xla_force_host_platform_device_count=1 to time one core.
"""

import sys

from hybridmarl.cli.main import main

if __name__ == "__main__":
    sys.exit(main(["bench", "engine", *sys.argv[1:]]))
