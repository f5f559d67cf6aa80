from parsph.cli.main import main

raise SystemExit(main())
