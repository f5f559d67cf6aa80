from parsph.cli import main

raise SystemExit(main())
