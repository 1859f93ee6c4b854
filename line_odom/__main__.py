from line_odom.cli import main

raise SystemExit(main())
