from mocapdb.cli.main import main

raise SystemExit(main())
