from rlgp_exec.cli import main

raise SystemExit(main())
