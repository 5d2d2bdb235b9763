from impress_gui.cli import main

raise SystemExit(main())
